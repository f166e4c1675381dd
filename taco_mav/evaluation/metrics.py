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


def along_cross(err_xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """ENU error vectors (N, 2), metres, split along and across the true heading (N,) ENU rad: (N, 2) columns
    along-track (positive ahead) and cross-track (positive to the left)."""
    e = np.asarray(err_xy, dtype=float).reshape(-1, 2)
    c, s = np.cos(heading), np.sin(heading)
    return np.column_stack([c * e[:, 0] + s * e[:, 1], -s * e[:, 0] + c * e[:, 1]])


def track_errors(est_xy: np.ndarray, gt_xy: np.ndarray, gt_heading: np.ndarray, est_theta0: float,
                 gt_theta0: float) -> np.ndarray:
    """Per-pose error (N, 2) along and across the true heading, metres, after the first-pose alignment that
    position_errors (and so the ATE) uses."""
    est = align_first_pose(np.asarray(est_xy, dtype=float), est_theta0, gt_xy, gt_theta0)
    return along_cross(est - np.asarray(gt_xy, dtype=float), np.asarray(gt_heading, dtype=float))


def fix_errors(capture_t: np.ndarray, fix_xy: np.ndarray, t: np.ndarray, gt_xy: np.ndarray,
               gt_heading: np.ndarray) -> np.ndarray:
    """Error of fixes (M, 2) along and across the true heading, metres: each fix xy (ENU metres, the reference
    point) against the ground truth (N poses at times t, s) interpolated at its capture time (M,), s."""
    tc = np.asarray(capture_t, dtype=float)
    if tc.size == 0:
        return np.zeros((0, 2))
    gt = np.asarray(gt_xy, dtype=float)
    truth = np.column_stack([np.interp(tc, t, gt[:, 0]), np.interp(tc, t, gt[:, 1])])
    heading = np.interp(tc, t, np.unwrap(np.asarray(gt_heading, dtype=float)))
    return along_cross(np.asarray(fix_xy, dtype=float).reshape(-1, 2) - truth, heading)


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


# --------------------------------------------------------------------------------------------- honest accuracy
# h_acc, the horizontal accuracy the Localiser reports (GPS_INPUT.horiz_accuracy; ArduPilot's EKF3 takes it as
# the 1-sigma of each of the north and east position observations), is a PER-AXIS 1-sigma: the square root of
# the largest eigenvalue of the reported 2x2 position covariance, i.e. the 1-sigma along the worst direction.
# It is not a CEP-like radius. Coverage is therefore the fraction of frames whose RADIAL error |e| is within
# k h_acc; for a Gaussian error with exactly that covariance it lies between the isotropic and the
# one-dimensional case (the ranges below), so "calibrated" means inside these bands, not at 68 / 95 %.
COVERAGE_GAUSSIAN_RANGE = {1: (1.0 - math.exp(-0.5), math.erf(1.0 / math.sqrt(2.0))),  # 39.3 .. 68.3 %
                           2: (1.0 - math.exp(-2.0), math.erf(2.0 / math.sqrt(2.0)))}  # 86.5 .. 95.4 %


def h_acc_from_var(var: np.ndarray) -> np.ndarray:
    """Per-axis 1-sigma horizontal accuracy, metres (N,): sqrt of the largest eigenvalue of each 2x2 position
    covariance given as rows (Pxx, Pxy, Pyy) in m^2, shape (N, 3)."""
    v = np.asarray(var, dtype=float).reshape(-1, 3)
    pxx, pxy, pyy = v[:, 0], v[:, 1], v[:, 2]
    lam = 0.5 * (pxx + pyy) + np.sqrt(0.25 * (pxx - pyy) ** 2 + pxy**2)
    return np.sqrt(np.maximum(lam, 0.0))


def coverage(errors: np.ndarray, h_acc: np.ndarray, k: float) -> float:
    """Fraction of frames whose radial horizontal error (m, (N,)) is within k reported per-axis 1-sigma h_acc
    (m, (N,)); NaN for no frames. A non-finite h_acc covers nothing."""
    e = np.asarray(errors, dtype=float)
    s = np.asarray(h_acc, dtype=float)
    if e.shape != s.shape:
        raise ValueError(f"coverage: errors {e.shape} and h_acc {s.shape} differ in shape")
    if e.size == 0:
        return float("nan")
    with np.errstate(invalid="ignore"):
        return float(np.mean(np.isfinite(s) & (e <= k * s)))
