"""taco+ (issue 7, beyond the paper): the pieces that replace the paper's heuristics in `Estimator.TACO_PLUS`.

- Process noise from the IMU's error growth instead of sigma_fwd >= 1 m per frame: a small position random
  walk plus a distance-proportional term, with the forward-speed error and the forward accelerometer bias
  carried as states (x[3] = dv, m/s: true minus preintegrated speed; x[4] = b, m/s^2: the preintegrated
  speed drifts by +b per second), each a random walk; optionally the compass bias (x[5] = beta, rad: the
  compass reads theta + beta), a first-order Gauss-Markov process.
- Adaptive fix noise (`FixNoiseScale`): the paper's w -> sigma mapping scaled by what the innovations of
  accepted fixes say the matcher's real accuracy is.
- A covariance trigger: ask for a fix when the filter's own 1-sigma horizontal uncertainty reaches
  `trigger_sigma_m` (or `trigger_time_s` passed while moving); the search cross is centred on the current
  estimate (no forward bias: our UKF is predicted to the capture time) and sized by that uncertainty;
  optionally also every `trigger_distance_m` driven since the last accepted fix (issue 18).
- Consensus over the candidates instead of argmax w, and a chi-square innovation gate beside the yaw gate
  (tighter for an answer no other crop agrees with).
- A hexagonal grid search, sized by the uncertainty, while lock is lost (`lock.py`).
- The reported accuracy (`VarianceFactor`, issue 18): the filter's covariance times the a-posteriori
  variance factor of the accepted fixes, so the h_acc sent covers the error as a 1-sigma should.

All lengths metres, angles radians, times seconds; body offsets (forward, left); world ENU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taco_mav.core import ukf_kernels as _kernels
from taco_mav.core.plus_params import PlusParams


def n_states(p: PlusParams) -> int:
    """5 (x, y, theta, dv, b), or 6 with the compass bias beta."""
    return 6 if p.compass_bias_sigma_rad > 0.0 else 5


def bias_decay(dt: float, p: PlusParams) -> float:
    """exp(-dt / tau) of the compass-bias Gauss-Markov process over dt seconds."""
    return math.exp(-dt / p.compass_bias_tau_s)


def process_noise_plus(theta: float, dt: float, distance: float, p: PlusParams, n: int | None = None) -> np.ndarray:
    """Q (5x5, or 6x6 with the compass bias) for one predict over `dt` seconds and `distance` metres at
    heading theta (ENU rad): position random walk plus distance-proportional body-frame terms rotated into
    ENU, heading, speed-error and bias random walks, and the compass bias's Gauss-Markov driving noise.
    n: the filter's size when it is larger (8: the map's offset, constant, zero rows); default n_states(p)."""
    n = n_states(p) if n is None else n
    q55 = p.compass_bias_sigma_rad**2 * (1.0 - bias_decay(dt, p) ** 2) if n >= 6 else 0.0
    return _kernels.process_noise_plus(float(theta), float(dt), float(distance), n, q55, p.q_pos_mps, p.q_fwd_per_m,
                                       p.q_lat_per_m, p.q_theta_rad, p.q_speed_mps, p.q_bias_mps2)  # compiled


def defer_answer(w: float, deferred: int, healthy: bool, sigma_h: float, since_fix_m: float, p: PlusParams) -> bool:
    """Issue 18: leave a weak answer unused and ask again? Yes when its consensus weight w is below defer_w, fewer
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


@dataclass
class FixNoiseScale:
    """Covariance matching for the fix noise: the matcher's nominal covariance R0 (from w) is scaled by s^2,
    learnt from the innovations of accepted fixes. For an innovation nu (ENU m) with prior position covariance
    P and nominal R0 (m^2), E[nu^T R0^-1 nu] = tr(P R0^-1) + 2 s^2, so each fix gives one sample of s^2; the
    samples are averaged (a running mean over the first `window` fixes, the prior s^2 = 1 counting as one
    sample, then exponentially over `window`) and s is clipped to [lo, hi]."""

    lo: float
    hi: float
    window: int
    s2: float = 1.0
    n: int = 0  # samples so far

    @property
    def scale(self) -> float:
        """The current sigma scale (dimensionless)."""
        return math.sqrt(self.s2)

    def update(self, innov: np.ndarray, P: np.ndarray, R0: np.ndarray) -> float:
        """Add one accepted fix; returns the new scale. A sample is capped at (2 hi)^2, so one outlier that
        slipped through the gates moves s^2 by at most that over `window`."""
        Ri = np.linalg.inv(R0)
        sample = 0.5 * (float(innov @ Ri @ innov) - float(np.trace(P @ Ri)))
        sample = min(max(sample, self.lo * self.lo), 4.0 * self.hi * self.hi)
        self.n += 1
        a = 1.0 / min(self.n + 1, self.window)
        self.s2 = min(max((1.0 - a) * self.s2 + a * sample, self.lo * self.lo), self.hi * self.hi)
        return self.scale


@dataclass
class VarianceFactor:
    """The a-posteriori variance factor of the accepted fixes (the "variance of unit weight" of a least-squares
    adjustment): the mean normalised innovation squared of a 2-D position fix is 2 when the filter's prior
    covariance P and the fix covariance R are right, 2 k when both are k times too large or too small, so
    k = mean(NIS) / 2 is the factor that makes the filter's covariance honest. Averaged like `FixNoiseScale`
    (the prior k = 1 counting as one sample, then exponentially over `window`), clipped to [lo, hi]."""

    lo: float
    hi: float
    window: int
    k: float = 1.0
    n: int = 0

    def update(self, nis: float) -> float:
        """Add one accepted fix's NIS (2 dof); returns the new factor. A non-finite NIS is ignored."""
        if not math.isfinite(nis):
            return self.factor
        self.n += 1
        a = 1.0 / min(self.n + 1, self.window)
        self.k = (1.0 - a) * self.k + a * 0.5 * min(max(float(nis), 0.0), 50.0)
        return min(max(self.k, self.lo), self.hi)

    def reset(self) -> None:
        """Forget the learnt factor (back to the prior k = 1), e.g. after a relocalisation."""
        self.k, self.n = 1.0, 0

    @property
    def factor(self) -> float:
        """The variance factor to apply to the reported covariance (dimensionless)."""
        return min(max(self.k, self.lo), self.hi)


