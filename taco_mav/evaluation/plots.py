"""Evaluation plots (matplotlib, PNG): trajectories over the mosaic, error versus distance, error CDF."""

from __future__ import annotations

import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from taco_mav.evaluation.metrics import cumulative_distance  # noqa: E402
from taco_mav.evaluation.runner import DriveRun  # noqa: E402

log = logging.getLogger(__name__)

SERIES = (("imu_only", "b-", "IMU only"), ("online", "r-", "TACO (UKF)"), ("smoothed", "m--", "TACO smoothed"))


def _mosaic_background(ax, run: DriveRun, margin_m: float = 60.0) -> None:
    """Draw the satellite mosaic under the trajectory (ENU metres rel. origin), if the run had one."""
    if not run.mosaic:
        return
    try:
        import rasterio
        from rasterio.windows import from_bounds

        xy = run.truth_xy
        e0, n0 = run.origin_utm
        left, right = xy[:, 0].min() - margin_m + e0, xy[:, 0].max() + margin_m + e0
        bottom, top = xy[:, 1].min() - margin_m + n0, xy[:, 1].max() + margin_m + n0
        with rasterio.open(run.mosaic) as ds:
            win = from_bounds(left, bottom, right, top, ds.transform).round_offsets().round_lengths()
            scale = max(1, int(max(win.width, win.height) // 2000))
            img = ds.read([1, 2, 3], window=win, boundless=True, fill_value=0,
                          out_shape=(3, int(win.height) // scale, int(win.width) // scale))
            b = rasterio.windows.bounds(win, ds.transform)
        ax.imshow(np.moveaxis(img, 0, -1), extent=(b[0] - e0, b[2] - e0, b[1] - n0, b[3] - n0), alpha=0.8)
    except Exception as exc:  # a plot must never fail an evaluation
        log.warning("no mosaic background for %s: %s", run.name, exc)


def plot_run(run: DriveRun, errors: dict[str, np.ndarray], out_dir: Path, label: str = "") -> list[Path]:
    """Write trajectory.png, error_vs_distance.png and error_cdf.png into out_dir; returns the paths. Each
    title names the drive and `label`, what made the run (`summary.made_by`: estimator and matcher)."""
    name = run.sequence or run.name
    suffix = f" ({label})" if label else ""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    fig, ax = plt.subplots(figsize=(8, 8))
    _mosaic_background(ax, run)
    ax.plot(run.truth_xy[:, 0], run.truth_xy[:, 1], "k-", lw=2, label="ground truth")
    ax.plot(run.imu_only_xy[:, 0], run.imu_only_xy[:, 1], "b-", lw=1, label="IMU only")
    ax.plot(run.online_xy[:, 0], run.online_xy[:, 1], "r-", lw=1.2, label="TACO (UKF)")
    if run.smoothed is not None:
        ax.plot(run.smoothed.poses[:, 0], run.smoothed.poses[:, 1], "m--", lw=1, label="TACO smoothed")
    acc = np.array([o.xy for o in run.outcomes if o.accepted and o.xy is not None]).reshape(-1, 2)
    rej = np.array([o.xy for o in run.outcomes if not o.accepted and o.xy is not None]).reshape(-1, 2)
    if len(acc):
        ax.scatter(acc[:, 0], acc[:, 1], s=10, c="lime", edgecolors="k", linewidths=0.3, label="accepted fixes", zorder=5)
    if len(rej):
        ax.scatter(rej[:, 0], rej[:, 1], s=14, c="orange", marker="x", label="rejected fixes", zorder=5)
    pad = 50.0
    ax.set_xlim(run.truth_xy[:, 0].min() - pad, run.truth_xy[:, 0].max() + pad)
    ax.set_ylim(run.truth_xy[:, 1].min() - pad, run.truth_xy[:, 1].max() + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(f"{name}: trajectories{suffix}")
    ax.legend(loc="best", fontsize=8)
    paths.append(out_dir / "trajectory.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    dist = cumulative_distance(run.truth_xy) / 1000.0
    fig, ax = plt.subplots(figsize=(8, 4))
    for key, style, label in SERIES:
        if key in errors:
            ax.plot(dist, errors[key], style, lw=1, label=label)
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("distance travelled (km)")
    ax.set_ylabel("position error (m)")
    ax.set_title(f"{name}: error vs distance{suffix}", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(out_dir / "error_vs_distance.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 4))
    for key, style, label in SERIES:
        if key in errors:
            e = np.sort(errors[key])
            ax.plot(e, np.arange(1, len(e) + 1) / len(e), style, label=label)
    ax.set_xscale("log")
    ax.set_xlabel("position error (m)")
    ax.set_ylabel("fraction of frames")
    ax.set_title(f"{name}: error CDF{suffix}", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(out_dir / "error_cdf.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)
    return paths
