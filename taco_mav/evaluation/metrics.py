"""Trajectory metrics (names as in DESIGN.md's results.json contract).

Trajectories are ENU metres (N, 2) with headings (N,) ENU radians at the same times as ground truth.
ATE is the RMSE of the position error after rigid first-pose alignment (paper Sec. IV-B): the estimate is
rotated about and translated onto the first ground-truth pose so that its first pose coincides with it.
"""

from __future__ import annotations

import math

import numpy as np


def align_first_pose(est_xy: np.ndarray, est_theta0: float, gt_xy: np.ndarray, gt_theta0: float) -> np.ndarray:
    """Rigidly move the estimate so its first pose equals the ground truth's first pose; returns (N, 2)."""
    d = gt_theta0 - est_theta0
    c, s = math.cos(d), math.sin(d)
    rel = np.asarray(est_xy, dtype=float) - est_xy[0]
    return gt_xy[0] + rel @ np.array([[c, s], [-s, c]])


def position_errors(est_xy: np.ndarray, gt_xy: np.ndarray, est_theta0: float | None = None,
                    gt_theta0: float | None = None) -> np.ndarray:
    """Per-pose horizontal error, metres (N,), after first-pose alignment when both headings are given."""
    est = np.asarray(est_xy, dtype=float)
    if est_theta0 is not None and gt_theta0 is not None:
        est = align_first_pose(est, est_theta0, gt_xy, gt_theta0)
    return np.linalg.norm(est - np.asarray(gt_xy, dtype=float), axis=1)


def rmse(errors: np.ndarray) -> float:
    """Root mean square of errors (0 for an empty array)."""
    e = np.asarray(errors, dtype=float)
    return float(np.sqrt(np.mean(e * e))) if e.size else 0.0


def path_length_m(xy: np.ndarray) -> float:
    """Length of a polyline, metres."""
    xy = np.asarray(xy, dtype=float)
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def cumulative_distance(xy: np.ndarray) -> np.ndarray:
    """Distance travelled at each pose, metres (N,)."""
    xy = np.asarray(xy, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def steady_state_rmse(errors: np.ndarray, times: np.ndarray, accepted_capture_times: list[float]) -> float:
    """RMSE of the per-pose error after the third accepted fix (paper Sec. IV-B); NaN with fewer fixes."""
    if len(accepted_capture_times) < 3:
        return float("nan")
    t3 = sorted(accepted_capture_times)[2]
    return rmse(np.asarray(errors)[np.asarray(times) >= t3])
