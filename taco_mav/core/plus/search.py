"""taco+'s trigger and search (beyond the paper): where to look and which answer to take.

- A covariance trigger: ask for a fix when the filter's own 1-sigma horizontal uncertainty reaches
  `trigger_sigma_m` (or `trigger_time_s` passed while moving); the search cross is centred on the current
  estimate (no forward bias: our UKF is predicted to the capture time) and sized by that uncertainty
  (`cross_arm`); optionally also every `trigger_distance_m` driven since the last accepted fix; a weak answer
  may be left unused and asked again (`defer_answer`).
- A hexagonal grid search, sized by the uncertainty, while lock is lost (`grid_rings`, `hex_offsets`; lock.py).
- Consensus over the candidates instead of argmax w (`consensus`).

All lengths metres, times seconds; body offsets (forward, left); world ENU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taco_mav.core.plus.params import PlusParams


def defer_answer(w: float, deferred: int, healthy: bool, sigma_h: float, since_fix_m: float, p: PlusParams) -> bool:
    """Leave a weak answer unused and ask again? Yes when its consensus weight w is below defer_w, fewer
    than defer_max answers were deferred in a row (`deferred`), the filter is healthy (locked, the safety guard
    quiet) with its prior 1-sigma sigma_h (m) below trigger_sigma_m, and fewer than trigger_distance_m +
    defer_span_m metres were driven since the last accepted fix (since_fix_m; defer_span_m 0: no limit)."""
    return (w < p.defer_w and deferred < p.defer_max and healthy and sigma_h < p.trigger_sigma_m
            and (p.defer_span_m <= 0.0 or since_fix_m < p.trigger_distance_m + p.defer_span_m))


def cross_arm(sigma_h: float, p: PlusParams) -> float:
    """Arm of the five-point cross, metres, from the 1-sigma horizontal uncertainty."""
    return min(max(p.cross_k * sigma_h, p.cross_min_m), p.cross_max_m)


def grid_rings(sigma_h: float, p: PlusParams) -> int:
    """Hexagonal rings needed to cover 3 sigma (at least 1, at most grid_max_rings)."""
    return int(min(max(math.ceil(3.0 * sigma_h / p.grid_spacing_m), 1), p.grid_max_rings))


def hex_offsets(rings: int, spacing: float) -> np.ndarray:
    """Body-frame offsets (forward, left), metres, of a hexagonal grid: the centre then ring 1, 2, ...
    (6 k points on ring k), shape (1 + 3 rings (rings + 1), 2). Every point of the disc of radius
    rings * spacing lies within spacing / sqrt(3) of a grid point."""
    pts = [(0.0, 0.0)]
    dirs = [(math.cos(a), math.sin(a)) for a in np.arange(6) * math.pi / 3.0]
    for k in range(1, rings + 1):
        for i in range(6):
            (ax, ay), (bx, by) = dirs[i], dirs[(i + 1) % 6]
            for j in range(k):
                pts.append((spacing * (k * ax + j * (bx - ax)), spacing * (k * ay + j * (by - ay))))
    return np.array(pts)


@dataclass(frozen=True)
class Consensus:
    """The chosen fix. index: the highest-weight member of the winning cluster; xy: w-weighted mean of the
    cluster, ENU metres; support: cluster size; weight: the best member's w."""

    index: int
    xy: np.ndarray
    support: int
    weight: float


def consensus(xy: np.ndarray, w: np.ndarray, usable: np.ndarray, radius_m: float,
              power: float = 1.0) -> Consensus | None:
    """Pick the cluster of usable candidates (world positions `xy` (K, 2), weights `w` (K,)) with the largest
    summed weight, members within `radius_m` of its seed; None when nothing is usable. The cluster mean weights
    each member by w^power (1: by w; 2: inverse variance under sigma ~ 1/w) and is reported with the best
    member's weight: nearby crops of one frame are not independent evidence."""
    idx = np.flatnonzero(usable)
    if idx.size == 0:
        return None
    pts, ws = xy[idx], w[idx]
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
    members = d <= radius_m
    score = members @ ws
    seed = int(np.argmax(score + 1e-9 * ws))  # ties: the heavier seed
    m = members[seed]
    best = int(idx[m][np.argmax(ws[m])])
    wm = ws[m] ** power
    mean = (wm[:, None] * pts[m]).sum(axis=0) / wm.sum()
    return Consensus(best, mean, int(m.sum()), float(w[best]))
