"""taco+'s noise model (beyond the paper): the process noise from the IMU's error growth
instead of the paper's sigma_fwd >= 1 m per frame, and what the accepted fixes teach about the noise.

- Process noise: a small position random walk plus a distance-proportional term, with the forward-speed error
  and the forward accelerometer bias carried as states (x[3] = dv, m/s: true minus preintegrated speed; x[4] = b,
  m/s^2: the preintegrated speed drifts by +b per second), each a random walk; optionally the compass bias
  (x[5] = beta, rad: the compass reads theta + beta), a first-order Gauss-Markov process.
- Adaptive fix noise (`FixNoiseScale`): the paper's w -> sigma mapping scaled by what the innovations of
  accepted fixes say the matcher's real accuracy is.
- The reported accuracy (`VarianceFactor`): the filter's covariance times the a-posteriori variance
  factor of the accepted fixes, so the h_acc sent covers the error as a 1-sigma should.

All lengths metres, angles radians, times seconds; world ENU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taco_mav.core import kernels as _kernels
from taco_mav.core.plus.params import PlusParams


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
