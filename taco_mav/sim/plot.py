"""Trajectory plot of a simulator run: ground truth vs the GPS_INPUT positions the autopilot received, over a
thumbnail of the satellite mosaic when there is one. Axes are ENU metres relative to the drive's origin."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from taco_mav.geo import UtmProjector  # noqa: E402
from taco_mav.sim.gps_mav import GpsUpdate  # noqa: E402
from taco_mav.sim.source import SimDrive  # noqa: E402

log = logging.getLogger(__name__)

__all__ = ["plot_gps_input"]


def _mosaic(ax: plt.Axes, mosaic: Path, drive: SimDrive, xy: np.ndarray, margin_m: float = 40.0) -> None:
    """Draw the GeoTIFF (UTM, north-up) under the plot, decimated to at most ~1500 px."""
    try:
        import rasterio
        from rasterio.windows import from_bounds

        e0, n0 = drive.origin_utm
        left, right = xy[:, 0].min() - margin_m + e0, xy[:, 0].max() + margin_m + e0
        bottom, top = xy[:, 1].min() - margin_m + n0, xy[:, 1].max() + margin_m + n0
        with rasterio.open(mosaic) as ds:
            win = from_bounds(left, bottom, right, top, ds.transform).round_offsets().round_lengths()
            scale = max(1, int(max(win.width, win.height) // 1500))
            img = ds.read([1, 2, 3], window=win, boundless=True, fill_value=0,
                          out_shape=(3, max(1, int(win.height) // scale), max(1, int(win.width) // scale)))
            b = rasterio.windows.bounds(win, ds.transform)
        ax.imshow(np.moveaxis(img, 0, -1), extent=(b[0] - e0, b[2] - e0, b[1] - n0, b[3] - n0), alpha=0.85)
    except Exception as exc:  # noqa: BLE001 - a plot must never fail a run
        log.warning("no mosaic under the plot (%s): %s", mosaic, exc)


def plot_gps_input(drive: SimDrive, updates: Sequence[GpsUpdate], play_start: float, out_png: Path,
                   mosaic: Path | None = None, title: str = "") -> Path:
    """Write the plot to `out_png` (PNG); returns its path. Updates with fix_type < 3 are drawn apart."""
    t = np.array([u.t - play_start for u in updates])
    keep = (t >= 0) & (t <= drive.t[-1]) if len(t) else np.zeros(0, bool)
    truth = drive.truth.xy
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    if len(t) and keep.any():
        proj = UtmProjector(drive.utm_epsg)
        e, n = proj.to_utm(np.array([u.lat for u in updates]), np.array([u.lon for u in updates]))
        est = (np.c_[np.atleast_1d(e), np.atleast_1d(n)] - drive.origin_utm)[keep]
        fix3 = np.array([u.fix_type >= 3 for u in updates])[keep]
    else:
        est, fix3 = np.zeros((0, 2)), np.zeros(0, bool)
    if mosaic is not None:
        _mosaic(ax, mosaic, drive, np.vstack([truth, est]) if len(est) else truth)
    ax.plot(truth[:, 0], truth[:, 1], "-", color="white", lw=3.0, alpha=0.9)
    ax.plot(truth[:, 0], truth[:, 1], "-", color="tab:green", lw=1.6, label="ground truth")
    if len(est):
        ax.plot(est[fix3, 0], est[fix3, 1], ".", color="tab:red", ms=3, label="GPS_INPUT (3D fix)")
        if (~fix3).any():
            ax.plot(est[~fix3, 0], est[~fix3, 1], "x", color="tab:orange", ms=4, label="GPS_INPUT (no fix)")
    ax.plot([0.0], [0.0], "o", color="black", ms=6, label="start (GNSS origin)")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(title or drive.name)
    ax.legend(loc="best", fontsize=8)
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, bbox_inches="tight")
    plt.close(fig)
    return out_png
