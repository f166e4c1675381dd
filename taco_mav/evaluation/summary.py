"""Turn a DriveRun into the results.json metrics (names per DESIGN.md) and the paper-style tables."""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from taco_mav.core.frames import FixOutcome
from taco_mav.daemon.survey import SurveyAnswer, stretches, verdict
from taco_mav.evaluation.metrics import (coverage, fix_errors, h_acc_from_var, path_length_m, position_errors, rmse,
                                         steady_state_rmse, track_errors)
from taco_mav.evaluation.runner import DriveRun

REPRESENTATIVE = ("00", "02", "05", "06", "08", "10")
NON_REPRESENTATIVE = ("01", "04")


def _num(x: float) -> float | None:
    """A JSON-safe float (None for NaN/inf), rounded to 4 decimals."""
    return round(float(x), 4) if math.isfinite(x) else None


def errors(run: DriveRun) -> dict[str, np.ndarray]:
    """Per-frame horizontal errors (m) of each trajectory after rigid first-pose alignment."""
    th0 = float(run.truth_theta[0])
    out = {
        "online": position_errors(run.online_xy, run.truth_xy, float(run.online_theta[0]), th0),
        "imu_only": position_errors(run.imu_only_xy, run.truth_xy, float(run.online_theta[0]), th0),
    }
    if run.smoothed is not None:
        out["smoothed"] = position_errors(run.smoothed.poses[:, :2], run.truth_xy, float(run.smoothed.poses[0, 2]), th0)
    return out


def metrics(run: DriveRun) -> dict[str, Any]:
    """The per-sequence metrics of results.json."""
    err = errors(run)
    length_km = path_length_m(run.truth_xy) / 1000.0
    accepted = [o for o in run.outcomes if o.accepted]
    attempts = len(run.outcomes)
    ate = rmse(err["online"])
    reasons = Counter(o.reason for o in run.outcomes if not o.accepted)
    per_km = (lambda v: v / length_km) if length_km > 0 else (lambda v: float("nan"))
    return {
        "ate_m": _num(ate),
        "ate_imu_only_m": _num(rmse(err["imu_only"])),
        "ate_smoothed_m": _num(rmse(err["smoothed"])) if "smoothed" in err else None,
        "length_km": _num(length_km),
        "ate_m_per_km": _num(per_km(ate)),
        "steady_rmse_m": _num(steady_state_rmse(err["online"], run.t, [o.capture_t for o in accepted])),
        "fixes_per_km": _num(per_km(len(accepted))),
        "attempts": attempts,
        "accepted": len(accepted),
        "camera_duty_cycle": _num(attempts / run.frames_available if run.frames_available else 0.0),
        **error_directions(run, accepted),
        "max_error_m": _num(float(err["online"].max())),
        "p95_error_m": _num(float(np.percentile(err["online"], 95))),
        "imu_only_drift_m_per_km": _num(per_km(rmse(err["imu_only"]))),
        "rejected": dict(sorted(reasons.items())),
        "honest_fraction": _num(honest_fraction(err["online"], run.online_var)),
        **accuracy_coverage(err["online"], reported_var(run)),
        "lock_losses": sum(1 for _, kind, _ in run.extra.get("lock_events", []) if kind == "lock_lost"),
        "lock_recoveries": sum(1 for _, kind, _ in run.extra.get("lock_events", []) if kind == "recovered"),
        "loop_closures": len(run.smoothed.loop_closures) if run.smoothed is not None else 0,
        "search_centre_error_median_m": _num(float(np.median(run.extra["search_centre_errors"])))
        if run.extra.get("search_centre_errors") else None,
        "matcher_s_per_100m": _num(run.matcher_s / (length_km * 10.0) if length_km > 0 else float("nan")),
        "survey": survey(run),
        "duration_s": _num(float(run.t[-1] - run.t[0])),
        "wall_s": _num(run.wall_s),
    }


def survey_answers(run: DriveRun) -> list[SurveyAnswer]:
    """Every answered camera query as the survey sees it (daemon/survey.py): metres driven at its capture (along
    the truth), whether it was accepted, and its position against the truth there (for a recording, the
    receiver), m (nan without a position)."""
    seg = np.r_[0.0, np.cumsum(np.hypot(*np.diff(run.truth_xy, axis=0).T))]
    out = []
    for o in run.outcomes:
        odo = float(np.interp(o.capture_t, run.t, seg))
        err = float("nan")
        if o.xy is not None and np.all(np.isfinite(o.xy)):
            tx = np.interp(o.capture_t, run.t, run.truth_xy[:, 0])
            ty = np.interp(o.capture_t, run.t, run.truth_xy[:, 1])
            err = float(np.hypot(o.xy[0] - tx, o.xy[1] - ty))
        out.append(SurveyAnswer(float(o.capture_t), odo, bool(o.accepted), err))
    return out


def survey(run: DriveRun) -> dict[str, Any]:
    """The survey verdict over the drive and per stretch (daemon/survey.py): are camera fixes usable here?"""
    answers = survey_answers(run)
    return {"drive": verdict(answers).as_dict(), "stretches": [v.as_dict() for v in stretches(answers)]}


def error_directions(run: DriveRun, accepted: list[FixOutcome]) -> dict[str, float | None]:
    """Where the error lies: RMS of the online error along and across the true heading (the ATE's alignment)
    and of the accepted fixes' error against the truth at their capture time, metres (None without fixes)."""
    track = track_errors(run.online_xy, run.truth_xy, run.truth_theta, float(run.online_theta[0]),
                         float(run.truth_theta[0]))
    fixes = fix_errors(np.array([o.capture_t for o in accepted]), np.array([o.xy for o in accepted]), run.t,
                       run.truth_xy, run.truth_theta)
    fix_rms = (lambda k: _num(rmse(fixes[:, k]))) if len(fixes) else (lambda k: None)
    return {"ate_along_m": _num(rmse(track[:, 0])), "ate_cross_m": _num(rmse(track[:, 1])),
            "fix_error_along_rms_m": fix_rms(0), "fix_error_cross_rms_m": fix_rms(1)}


def reported_var(run: DriveRun) -> np.ndarray:
    """The reported position covariance per frame (Pxx, Pxy, Pyy, m^2): what the Localiser's estimate said,
    else the filter's own."""
    return run.reported_var if run.reported_var is not None else run.online_var


def accuracy_coverage(err: np.ndarray, var: np.ndarray) -> dict[str, Any]:
    """How honest the reported accuracy is over one run: the fraction of frames whose radial error (m) lies
    within 1 and 2 reported h_acc (a per-axis 1-sigma, see metrics.COVERAGE_GAUSSIAN_RANGE), the median h_acc
    and the frame count (for pooling)."""
    h = h_acc_from_var(var)
    return {"coverage_1sigma": _num(coverage(err, h, 1.0)), "coverage_2sigma": _num(coverage(err, h, 2.0)),
            "h_acc_median_m": _num(float(np.median(h))) if len(h) else None, "coverage_frames": int(len(err))}


def pooled_coverage(per_seq: dict[str, dict[str, Any]], key: str) -> float | None:
    """A coverage over all frames of all sequences (each sequence weighted by its frame count)."""
    rows = [(m[key], m["coverage_frames"]) for m in per_seq.values()
            if m.get(key) is not None and m.get("coverage_frames")]
    n = sum(f for _, f in rows)
    return _num(sum(c * f for c, f in rows) / n) if n else None


def honest_fraction(err: np.ndarray, var: np.ndarray) -> float:
    """Fraction of frames whose true error (m) is within 3 reported 1-sigma (sqrt of the largest eigenvalue
    of the position covariance; var columns Pxx, Pxy, Pyy in m^2)."""
    pxx, pxy, pyy = var[:, 0], var[:, 1], var[:, 2]
    lam = 0.5 * (pxx + pyy) + np.sqrt(0.25 * (pxx - pyy) ** 2 + pxy**2)
    return float(np.mean(err <= 3.0 * np.sqrt(np.maximum(lam, 0.0)))) if len(err) else float("nan")


def summary(per_seq: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Medians over the sequences run (all, and the paper's representative / non-representative groups)."""
    def med(key: str, names) -> float | None:
        vals = [per_seq[n][key] for n in names if n in per_seq and per_seq[n][key] is not None]
        return _num(float(np.median(vals))) if vals else None

    names = list(per_seq)
    out: dict[str, Any] = {"median_ate_m": med("ate_m", names), "median_ate_imu_only_m": med("ate_imu_only_m", names),
                           "median_ate_smoothed_m": med("ate_smoothed_m", names),
                           "median_fixes_per_km": med("fixes_per_km", names), "sequences_run": len(names),
                           "coverage_1sigma": pooled_coverage(per_seq, "coverage_1sigma"),
                           "coverage_2sigma": pooled_coverage(per_seq, "coverage_2sigma")}
    for group, members in (("representative", REPRESENTATIVE), ("non_representative", NON_REPRESENTATIVE)):
        if any(m in per_seq for m in members):
            out[f"{group}_median_ate_m"] = med("ate_m", members)
            out[f"{group}_median_ate_m_per_km"] = med("ate_m_per_km", members)
    return out


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.2f}" if abs(v) < 100 else f"{v:.1f}"
    return str(v)


ROWS = (("IMU only ATE (m)", "ate_imu_only_m"), ("TACO ATE (m)", "ate_m"), ("TACO ATE (m/km)", "ate_m_per_km"),
        ("TACO steady-state RMSE (m)", "steady_rmse_m"), ("TACO fixes/km", "fixes_per_km"),
        ("TACO smoothed (m)", "ate_smoothed_m"), ("attempts / accepted", None), ("camera duty cycle", "camera_duty_cycle"),
        ("max error (m)", "max_error_m"), ("length (km)", "length_km"),
        ("error within 1 h_acc (1-sigma)", "coverage_1sigma"), ("error within 2 h_acc (2-sigma)", "coverage_2sigma"))


def made_by(estimator: str, matcher: str) -> str:
    """What made a table or plot, said the same way everywhere: "estimator paper, matcher emulator"."""
    return f"estimator {estimator}, matcher {matcher}"


def table_md(per_seq: dict[str, dict[str, Any]], label: str = "") -> str:
    """A Markdown table laid out like the paper's Table I: representative sequences, their median, then the
    non-representative ones and their median (whichever were run), then any other drives. `label` (see
    `made_by`) is written above it."""
    rep = [s for s in REPRESENTATIVE if s in per_seq]
    non = [s for s in NON_REPRESENTATIVE if s in per_seq]
    other = [s for s in per_seq if s not in rep and s not in non]
    cols: list[tuple[str, list[str] | str]] = [(s, s) for s in rep]
    if rep:
        cols.append(("Median (rep.)", rep))
    cols += [(s, s) for s in non]
    if non:
        cols.append(("Median (non-rep.)", non))
    cols += [(s, s) for s in other]
    lines = [f"TACO, {label}", ""] if label else []
    lines += ["| System | " + " | ".join(c for c, _ in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for row, key in ROWS:
        cells = []
        for _, src in cols:
            if isinstance(src, list):
                vals = [per_seq[s][key] for s in src if key and per_seq[s].get(key) is not None]
                cells.append(_fmt(float(np.median(vals))) if vals else "-")
            elif key is None:
                cells.append(f"{per_seq[src]['attempts']} / {per_seq[src]['accepted']}")
            else:
                cells.append(_fmt(per_seq[src].get(key)))
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


ABLATION_LABELS = {"full": "TACO (full)", "no_yaw_gate": "- no yaw-residual gate", "single_crop": "- single crop",
                   "isotropic_noise": "- isotropic noise", "no_forward_bias": "- no forward bias",
                   "ukf_only": "- no Pose2 smoother (UKF only)",
                   "no_distance_trigger": "- taco+: no distance trigger (covariance and time only)",
                   "no_report_calibration": "- taco+: reported accuracy = filter covariance",
                   "w_weighted_consensus": "- taco+: crop answers averaged by w (not w^2)",
                   "no_deferral": "- taco+: weak answers used at once (not deferred)"}


def ablation_md(ablations: dict[str, dict[str, Any]]) -> str:
    """The paper's Table III: ATE/km (median over the sequences run) per configuration, plus accepted fixes."""
    lines = ["| Configuration | ATE / km (m/km) | median ATE (m) | accepted / attempts |", "|---|---|---|---|"]
    for name, res in ablations.items():
        lines.append(f"| {ABLATION_LABELS.get(name, name)} | {_fmt(res['median_ate_m_per_km'])} | "
                     f"{_fmt(res['median_ate_m'])} | {res['accepted']} / {res['attempts']} |")
    return "\n".join(lines) + "\n"
