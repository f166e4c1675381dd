"""`taco-mav eval`: evaluate sequences or drives, write results.json, table.md, the resolved config,
trajectories (TUM, KITTI) and plots into one run folder. Deterministic: same inputs and seed, same numbers."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from taco_mav.config import Estimator, Profile, load_profile, profile_from_dict, profile_to_dict, replace_in
from taco_mav.datasets.kitti import ODOMETRY_SEQUENCES, load_drive, load_sequence
from taco_mav.errors import ConfigError, DataError
from taco_mav.evaluation.export import write_kitti, write_tum
from taco_mav.evaluation.plots import plot_run
from taco_mav.evaluation.runner import DriveRun, run_drive
from taco_mav.evaluation.summary import ablation_md, errors, made_by, metrics, summary, table_md

log = logging.getLogger(__name__)

# Ablations of the paper's Table III, each a set of profile overrides.
ABLATIONS: dict[str, dict[str, Any]] = {
    "full": {},
    "no_yaw_gate": {"gate.enabled": False},
    "single_crop": {"trigger.multi_crop": False},
    "isotropic_noise": {"ukf.anisotropic": False},
    "no_forward_bias": {"trigger.forward_bias": False},
    "ukf_only": {"smoother.enabled": False},
    # taco+; with --estimator paper these change nothing
    "no_distance_trigger": {"plus.trigger_distance_m": 0.0},
    "no_report_calibration": {"plus.report_calibration": False},
    "w_weighted_consensus": {"plus.consensus_weight_power": 1.0},
    "no_deferral": {"plus.defer_w": 0.0},
    "no_map_offset": {"map.georef_sigma_m": 0.0},
}


@dataclass(frozen=True)
class EvalRequest:
    """What to evaluate. Either kitti_root + sequences (odometry ids) or drives (KITTI-layout drive dirs)."""

    out: Path
    profile: str | Path = "kitti"
    kitti_root: Path | None = None
    sequences: tuple[str, ...] = ()
    drives: tuple[Path, ...] = ()
    matcher: str | None = None
    ablations: tuple[str, ...] = ()
    seed: int = 0
    latency_s: float = 0.0
    apply_on_arrival: bool = False
    estimator: str | None = None
    cross_area: bool = False  # the emulator's FG2 cross-area figures for every drive (else per the profile)
    plots: bool = True
    progress: bool = True
    recording: tuple[Path, Path, Path] | None = None  # a recorded session: (mav.tlog, frames/, map GeoTIFF)


def resolve_profile(req: EvalRequest) -> Profile:
    """The profile with the command line's overrides applied."""
    profile = load_profile(req.profile)
    if req.matcher:
        profile = replace_in(profile, "matcher", req.matcher)
    if req.estimator:
        try:
            est = Estimator(req.estimator)
        except ValueError:
            raise ConfigError(f"--estimator: {req.estimator!r} is not one of paper, taco+") from None
        profile = replace_in(profile, "estimator", est)
    profile = replace_in(profile, "emulator.seed", int(req.seed))
    if req.cross_area:
        if profile.matcher != "emulator":
            raise ConfigError(f"--cross-area: only the emulator has cross-area figures (matcher is {profile.matcher})")
        profile = replace_in(profile, "emulator.cross_area_sequences", tuple(req.sequences))
    if req.apply_on_arrival:
        profile = replace_in(profile, "latency.apply_on_arrival", True)
    if req.latency_s < 0:
        raise ConfigError(f"--matcher-latency: {req.latency_s} must be >= 0")
    return profile_from_dict(profile_to_dict(profile), "command line")  # re-validates the overrides


def load_drives(req: EvalRequest) -> list:
    """The drives a request names: KITTI odometry sequences under --kitti-root, or --drive folders."""
    if req.recording is not None:
        from taco_mav.datasets.recording import load_recording

        tlog, frames, mosaic = req.recording
        return [load_recording(tlog, frames, mosaic)]
    if req.sequences and req.drives:
        raise ConfigError("give either --sequences (with --kitti-root) or --drive, not both")
    if req.sequences:
        if req.kitti_root is None:
            raise ConfigError("--sequences needs --kitti-root DIR (the KITTI raw root)")
        for s in req.sequences:
            if s.zfill(2) not in ODOMETRY_SEQUENCES:
                raise DataError(f"unknown sequence {s!r} (known: {', '.join(sorted(ODOMETRY_SEQUENCES))})")
        return [load_sequence(Path(req.kitti_root), s) for s in req.sequences]
    if req.drives:
        return [load_drive_dir(Path(d)) for d in req.drives]
    raise ConfigError("nothing to evaluate: give --kitti-root DIR --sequences LIST or --drive DIR")


def load_drive_dir(path: Path):
    """A KITTI-layout drive dir, or a synthetic world (its folder or the drive inside it: the world's exact
    truth and rendered frames are then used)."""
    if not path.is_dir():
        raise DataError(f"{path}: drive directory not found")
    for folder in (path, *path.parents[:3]):
        if (folder / "world.json").is_file():
            from taco_mav.datasets.synthetic import load_world

            return load_world(folder)
    return load_drive(path)


def _key(drive) -> str:
    return drive.sequence or drive.name


def _run_all(drives: list, profile: Profile, req: EvalRequest) -> dict[str, DriveRun]:
    runs = {}
    for drive in drives:
        cross = req.cross_area or (drive.sequence or "") in profile.emulator.cross_area_sequences
        runs[_key(drive)] = run_drive(drive, profile, latency_s=req.latency_s, progress=req.progress, cross_area=cross)
    return runs


def _write_run(run: DriveRun, folder: Path, plots: bool, label: str = "") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    write_tum(folder / "truth.tum", run.t, run.truth_xy, run.truth_theta)
    write_tum(folder / "online.tum", run.t, run.online_xy, run.online_theta)
    write_kitti(folder / "online.kitti", run.online_xy, run.online_theta)
    write_kitti(folder / "truth.kitti", run.truth_xy, run.truth_theta)
    write_tum(folder / "imu_only.tum", run.t, run.imu_only_xy, run.online_theta)
    if run.smoothed is not None:
        write_tum(folder / "smoothed.tum", run.t, run.smoothed.poses[:, :2], run.smoothed.poses[:, 2])
    with (folder / "fixes.jsonl").open("w") as f:
        for o in run.outcomes:
            f.write(json.dumps({"query_id": o.query_id, "accepted": o.accepted, "reason": o.reason,
                                "capture_t": o.capture_t, "arrival_t": o.arrival_t, "chosen": o.chosen,
                                "xy": None if o.xy is None else [round(float(v), 4) for v in o.xy],
                                "yaw_residual": round(o.yaw_residual, 5), "weights": [round(w, 4) for w in o.weights]}) + "\n")
    if plots:
        plot_run(run, errors(run), folder, label)


def evaluate(req: EvalRequest) -> dict[str, Any]:
    """Run the evaluation described by `req`; returns the results.json object (also written to req.out)."""
    profile = resolve_profile(req)
    drives = load_drives(req)
    out = Path(req.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = _run_all(drives, profile, req)
    per_seq = {k: metrics(r) for k, r in runs.items()}
    label = made_by(profile.estimator.value, profile.matcher)  # on every table and plot
    for k, r in runs.items():
        _write_run(r, out / k, req.plots, label)
    results: dict[str, Any] = {
        "sequences": per_seq,
        "summary": summary(per_seq),
        "config": profile_to_dict(profile),
        "run": {"matcher": profile.matcher, "estimator": profile.estimator.value, "seed": req.seed,
                "matcher_latency_s": req.latency_s, "apply_on_arrival": profile.latency.apply_on_arrival},
    }
    table = table_md(per_seq, label)
    names = list(ABLATIONS) if "all" in req.ablations else list(req.ablations)
    if names:
        unknown = [n for n in names if n not in ABLATIONS]
        if unknown:
            raise ConfigError(f"--ablation: unknown {', '.join(unknown)} (known: all, {', '.join(ABLATIONS)})")
        results["ablations"] = {}
        for name in names:
            prof = profile
            for key, value in ABLATIONS[name].items():
                prof = replace_in(prof, key, value)
            arun = runs if name == "full" else _run_all(drives, prof, req)
            seqs = {k: metrics(r) for k, r in arun.items()}
            # "full" is the whole pipeline, smoother included (Table III); "ukf_only" drops the smoother.
            score = "ate_smoothed_m" if prof.smoother.enabled else "ate_m"
            per_km = [s[score] / s["length_km"] for s in seqs.values() if s[score] is not None and s["length_km"]]
            ates = [s[score] for s in seqs.values() if s[score] is not None]
            results["ablations"][name] = {
                "sequences": seqs, "overrides": ABLATIONS[name], "scored_on": score,
                "median_ate_m_per_km": round(float(np.median(per_km)), 4) if per_km else None,
                "median_ate_m": round(float(np.median(ates)), 4) if ates else None,
                "attempts": sum(s["attempts"] for s in seqs.values()),
                "accepted": sum(s["accepted"] for s in seqs.values())}
        table += "\n## Ablations\n\n" + ablation_md(results["ablations"])
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    (out / "table.md").write_text(table)
    (out / "config.yaml").write_text(yaml.safe_dump(profile_to_dict(profile), sort_keys=False))
    return results
