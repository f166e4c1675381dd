"""Score the GPS_INPUT stream the simulated autopilot received against the drive's ground truth.

Each kept update is placed at its arrival on the autopilot clock (what ArduPilot does: the fix is "now" when it
lands), converted to drive time, and compared with the truth interpolated there. lat/lon go to UTM in the
drive's zone and are taken relative to the drive's origin (ENU metres). ATE (DESIGN.md) is the RMSE after
rigid first-pose alignment (`taco_mav.evaluation.metrics`): when the first update reports a yaw, the estimate
is turned and shifted so its first pose matches the truth; without one it is already in the truth's frame
(both start at the same GNSS origin) and is left as it is. `ate_unaligned_m` is the plain RMSE in UTM.
`ate_denied_m` / `max_error_denied_m`: the same errors over the updates from `denied_from_s` of drive time on
(when GNSS is denied or spoofed), the figures that matter for a GNSS substitute.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from taco_mav.evaluation.metrics import path_length_m, position_errors, rmse
from taco_mav.geo import UtmProjector, grid_convergence, wrap_angle
from taco_mav.sim.gps_mav import GpsUpdate
from taco_mav.sim.source import SimDrive

__all__ = ["score_updates", "results_document"]


def _truth_at(drive: SimDrive, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tr = drive.truth
    xy = np.c_[np.interp(t, tr.t, tr.xy[:, 0]), np.interp(t, tr.t, tr.xy[:, 1])]
    return xy, wrap_angle(np.interp(t, tr.t, np.unwrap(tr.heading)))


def score_updates(drive: SimDrive, updates: Sequence[GpsUpdate], play_start: float,
                  play_end: float | None = None, denied_from_s: float | None = None) -> dict[str, Any]:
    """Per-drive figures for `updates` received while `drive` played from autopilot time `play_start` (s) to
    `play_end` (s; None: to the drive's end); denied_from_s: drive time (s) from which GNSS is denied or
    spoofed (None: never, no `ate_denied_m`).

    Only updates within the played span are scored; `ate_m` uses those with a 3D fix (what the EKF may
    consume), `ate_all_m` every one. Returns a dict of results.json sequence fields (NaN-free: absent figures
    are None).
    """
    t = np.array([u.t - play_start for u in updates])
    last = float(drive.t[-1]) if play_end is None else min(float(drive.t[-1]), play_end - play_start)
    inside = (t >= drive.t[0]) & (t <= last) if len(t) else np.zeros(0, dtype=bool)
    fix3 = np.array([u.fix_type >= 3 for u in updates], dtype=bool) & inside if len(t) else inside
    out: dict[str, Any] = {"scored_updates": int(fix3.sum()), "scored_updates_all": int(inside.sum())}
    if not fix3.any():
        out.update(ate_m=None, ate_unaligned_m=None, ate_all_m=None, length_km=0.0, ate_m_per_km=None,
                   max_error_m=None, final_error_m=None)
        if denied_from_s is not None:
            out.update(ate_denied_m=None, max_error_denied_m=None, denied_from_s=denied_from_s, denied_updates=0)
        return out
    proj = UtmProjector(drive.utm_epsg)
    lat = np.array([u.lat for u in updates])
    lon = np.array([u.lon for u in updates])
    e, n = proj.to_utm(lat, lon)
    est_all = np.c_[np.atleast_1d(e), np.atleast_1d(n)] - drive.origin_utm
    gt_all, gt_heading = _truth_at(drive, t)

    idx = np.flatnonzero(fix3)
    est, gt = est_all[idx], gt_all[idx]
    first = updates[int(idx[0])]
    est_theta0 = gt_theta0 = None
    if first.yaw_deg is not None:
        true_enu = math.pi / 2.0 - math.radians(first.yaw_deg)
        est_theta0 = float(wrap_angle(true_enu + float(grid_convergence(first.lat, first.lon, drive.utm_epsg))))
        gt_theta0 = float(gt_heading[idx[0]])
    err = position_errors(est, gt, est_theta0, gt_theta0)
    err_raw = np.linalg.norm(est - gt, axis=1)
    err_all = np.linalg.norm(est_all[inside] - gt_all[inside], axis=1)
    t_lo, t_hi = float(t[idx[0]]), float(t[idx[-1]])
    keep = (drive.truth.t >= t_lo) & (drive.truth.t <= t_hi)
    length_km = path_length_m(np.vstack([gt[:1], drive.truth.xy[keep], gt[-1:]])) / 1000.0
    ate = rmse(err)
    out.update(
        ate_m=ate, ate_unaligned_m=rmse(err_raw), ate_all_m=rmse(err_all), length_km=length_km,
        ate_m_per_km=ate / length_km if length_km > 0 else None, max_error_m=float(err.max()),
        p95_error_m=float(np.percentile(err, 95)), final_error_m=float(err[-1]),
        first_pose_aligned=est_theta0 is not None, scored_from_s=t_lo, scored_to_s=t_hi,
        fix3_fraction=float(fix3.sum() / max(1, inside.sum())),
    )
    if denied_from_s is not None:
        denied = t[idx] >= denied_from_s
        out.update(ate_denied_m=rmse(err[denied]) if denied.any() else None,
                   max_error_denied_m=float(err[denied].max()) if denied.any() else None,
                   denied_from_s=float(denied_from_s), denied_updates=int(denied.sum()))
    stamps = [(u.stamp_unix_s - drive.utc0) - tt for u, tt in zip(updates, t) if u.stamp_unix_s is not None]
    if stamps and abs(float(np.median(stamps))) < 60.0:  # a companion on another calendar says nothing here
        out["stamp_minus_arrival_p50_ms"] = float(np.median(stamps) * 1e3)
    return out


def results_document(sequences: dict[str, dict[str, Any]], config: dict[str, Any]) -> dict[str, Any]:
    """The results.json object (DESIGN.md contract): sequences, summary (medians), config."""
    ates = [s["ate_m"] for s in sequences.values() if s.get("ate_m") is not None]
    summary: dict[str, Any] = {"median_ate_m": float(np.median(ates)) if ates else None}
    return {"sequences": sequences, "summary": summary, "config": config}
