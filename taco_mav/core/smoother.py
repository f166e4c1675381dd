"""Offline Pose2 factor-graph smoother with vetted loop closures (paper Sec. III-G).

One Pose2 node per processed frame (x, y ENU metres, theta ENU rad). Factors: an origin prior; odometry
between consecutive nodes from the preintegrated body increment; a weaker non-holonomic odometry factor with
the lateral component zeroed; a prior at every accepted fix; and loop closures between fix nodes that pass
the chord, frame-gap and path-to-chord tests. Solved by Levenberg-Marquardt, then Savitzky-Golay on easting
and northing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from taco_mav.core.params import SmootherParams


@dataclass(frozen=True)
class FixNode:
    """An accepted fix attached to node `node`: position xy (ENU metres) and its body sigmas (metres)."""

    node: int
    xy: np.ndarray
    sigma_fwd: float
    sigma_lat: float


@dataclass(frozen=True)
class SmoothResult:
    """poses: (N, 3) smoothed x, y (ENU metres) and theta (rad); loop_closures: fix-node index pairs used."""

    poses: np.ndarray
    loop_closures: list[tuple[int, int]]


def loop_closure_pairs(fixes: Sequence[FixNode], path_cum: np.ndarray, max_chord_m: float = 50.0,
                       min_frame_gap: int = 30, min_path_ratio: float = 5.0) -> list[tuple[int, int]]:
    """Pairs (a, b) of indices into `fixes` (a < b) passing all three tests: chord between the fix positions
    <= max_chord_m; node gap >= min_frame_gap; path length between the nodes / chord >= min_path_ratio.
    path_cum: (N,) cumulative odometry path length at each node, metres."""
    if len(fixes) < 2:
        return []
    from scipy.spatial import cKDTree  # offline only: the live daemon never smooths and never loads it

    pts = np.array([f.xy for f in fixes])
    pairs = []
    for a, b in sorted(cKDTree(pts).query_pairs(max_chord_m)):
        fa, fb = fixes[a], fixes[b]
        if abs(fb.node - fa.node) < min_frame_gap:
            continue
        chord = float(np.linalg.norm(fb.xy - fa.xy))
        path = abs(float(path_cum[fb.node] - path_cum[fa.node]))
        # A stop (path ~ 0, chord ~ 0) gives a ratio ~ 0, not infinity: it must not close a loop.
        if path / max(chord, 1e-6) >= min_path_ratio:
            pairs.append((a, b))
    return pairs


def smooth(initial: np.ndarray, increments: np.ndarray, odo_sigmas: np.ndarray, fixes: Sequence[FixNode],
           params: SmootherParams = SmootherParams()) -> SmoothResult:
    """Optimise the Pose2 graph. initial: (N, 3) node poses (the online UKF estimates); increments: (N-1, 3)
    body increments (forward m, left m, dtheta rad) between consecutive nodes; odo_sigmas: (N-1,) isotropic
    odometry sigmas, 1/2 (sigma_fwd + sigma_lat) of the frame's process noise, metres."""
    import gtsam  # offline only: the live daemon never smooths and never loads it (~40 MB)
    from scipy.signal import savgol_filter

    initial = np.asarray(initial, dtype=float)
    n = len(initial)
    if n == 0:
        return SmoothResult(np.zeros((0, 3)), [])
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, (x, y, th) in enumerate(initial):
        values.insert(i, gtsam.Pose2(x, y, th))
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*initial[0]), gtsam.noiseModel.Isotropic.Sigma(3, params.origin_sigma)))
    nonholonomic = gtsam.noiseModel.Isotropic.Sigma(3, params.nonholonomic_sigma_m)
    for i, ((dx, dy, dth), sigma) in enumerate(zip(increments, odo_sigmas)):
        graph.add(gtsam.BetweenFactorPose2(i, i + 1, gtsam.Pose2(dx, dy, dth), gtsam.noiseModel.Isotropic.Sigma(3, float(sigma))))
        graph.add(gtsam.BetweenFactorPose2(i, i + 1, gtsam.Pose2(dx, 0.0, dth), nonholonomic))
    for f in fixes:
        sigma = 0.5 * (f.sigma_fwd + f.sigma_lat)
        graph.add(gtsam.PriorFactorPose2(f.node, gtsam.Pose2(float(f.xy[0]), float(f.xy[1]), float(initial[f.node, 2])),
                                         gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
    path_cum = np.concatenate([[0.0], np.cumsum(np.hypot(increments[:, 0], increments[:, 1]))]) if n > 1 else np.zeros(1)
    pairs = loop_closure_pairs(fixes, path_cum, params.lc_max_chord_m, params.lc_min_frame_gap, params.lc_min_path_ratio)
    closures = []
    for a, b in pairs:
        fa, fb = fixes[a], fixes[b]
        pa = gtsam.Pose2(float(fa.xy[0]), float(fa.xy[1]), float(initial[fa.node, 2]))
        pb = gtsam.Pose2(float(fb.xy[0]), float(fb.xy[1]), float(initial[fb.node, 2]))
        sigma = max(math.hypot(fa.sigma_fwd, fb.sigma_fwd), params.lc_sigma_floor_m)
        graph.add(gtsam.BetweenFactorPose2(fa.node, fb.node, pa.between(pb), gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
        closures.append((fa.node, fb.node))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(params.lm_max_iterations)
    lm.setRelativeErrorTol(params.lm_relative_tolerance)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, lm).optimize()
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(i) for i in range(n))])
    w, order = params.savgol_window, params.savgol_order
    if w > order and n >= w:
        poses[:, 0] = savgol_filter(poses[:, 0], w, order)
        poses[:, 1] = savgol_filter(poses[:, 1], w, order)
    return SmoothResult(poses, closures)
