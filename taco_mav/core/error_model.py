"""IMU error envelope (paper Sec. III-B, eq. 1 and the composite trigger value).

eps_cross = k_c d(T) sigma_w sqrt(T)        (k_c = 3: a deliberate 3-sigma inflation)
eps_along = k_a sigma_a(T) T^2              (k_a = 1/2)
eps_IMU   = max(eps_cross, eps_along, k_d d_div)   (k_d = 0.03)

T: seconds since the anchor (last accepted fix); d(T): metres travelled since then; sigma_w: gyro angle random
walk, rad/sqrt(s); sigma_a(T): standard deviation of the high-pass-filtered forward acceleration residual
since the anchor, m/s^2; d_div: chord between the UKF position and the corrected preintegrator, metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


class HighPass:
    """First-order high-pass filter for irregular sample intervals: y_k = a (y_{k-1} + x_k - x_{k-1}),
    a = tau / (tau + dt), tau = 1 / (2 pi f_c). Input and output in the same unit (here m/s^2)."""

    def __init__(self, corner_hz: float) -> None:
        self.tau = 1.0 / (2.0 * math.pi * corner_hz)
        self.y = 0.0
        self.x_prev: float | None = None

    def step(self, x: float, dt: float) -> float:
        if self.x_prev is None:
            self.x_prev = x
            return 0.0
        a = self.tau / (self.tau + dt)
        self.y = a * (self.y + x - self.x_prev)
        self.x_prev = x
        return self.y


@dataclass(frozen=True, slots=True)
class Moments:
    """Count, mean and sum of squared deviations (Welford / Chan) of a scalar sample set."""

    n: int = 0
    mean: float = 0.0
    m2: float = 0.0

    def add(self, x: float) -> "Moments":
        n = self.n + 1
        delta = x - self.mean
        mean = self.mean + delta / n
        return Moments(n, mean, self.m2 + delta * (x - mean))

    def merge(self, other: "Moments") -> "Moments":
        if other.n == 0:
            return self
        if self.n == 0:
            return other
        n = self.n + other.n
        delta = other.mean - self.mean
        mean = self.mean + delta * other.n / n
        return Moments(n, mean, self.m2 + other.m2 + delta * delta * self.n * other.n / n)

    @property
    def std(self) -> float:
        """Population standard deviation (0 with fewer than two samples)."""
        return math.sqrt(self.m2 / self.n) if self.n > 1 else 0.0


class MomentAccumulator:
    """Mutable Welford accumulator for the per-sample hot path; `take()` returns and clears its Moments."""

    __slots__ = ("n", "mean", "m2")

    def __init__(self) -> None:
        self.n, self.mean, self.m2 = 0, 0.0, 0.0

    def add(self, x: float) -> None:
        self.n += 1
        delta = x - self.mean
        self.mean += delta / self.n
        self.m2 += delta * (x - self.mean)

    def take(self) -> Moments:
        m = Moments(self.n, self.mean, self.m2)
        self.n, self.mean, self.m2 = 0, 0.0, 0.0
        return m


@dataclass(frozen=True, slots=True)
class AnchorWindow:
    """What the error model knows since the anchor: elapsed T (s), distance d (m), residual moments."""

    elapsed: float = 0.0
    distance: float = 0.0
    residual: Moments = Moments()

    def extend(self, dt: float, distance: float, residual: Moments) -> "AnchorWindow":
        return AnchorWindow(self.elapsed + dt, self.distance + distance, self.residual.merge(residual))


@dataclass(frozen=True, slots=True)
class ErrorTerms:
    """The three terms of the envelope and their maximum, metres."""

    cross: float
    along: float
    divergence: float

    @property
    def epsilon(self) -> float:
        return max(self.cross, self.along, self.divergence)


def error_terms(window: AnchorWindow, d_div: float, gyro_arw: float, cross_k: float = 3.0,
                along_k: float = 0.5, divergence_k: float = 0.03) -> ErrorTerms:
    """Evaluate eq. (1) and the floor for an anchor window; all lengths metres."""
    T = window.elapsed
    cross = cross_k * window.distance * gyro_arw * math.sqrt(T)
    along = along_k * window.residual.std * T * T
    return ErrorTerms(cross, along, divergence_k * d_div)
