"""The satellite map's georeferencing offset, learnt from fixes while the position is anchored (taco+).

An orthophoto puts every feature up to a metre or two from where it really is (its georeferencing error): a
feature at world (x, y) appears in the map at (x + bx, y + by), local ENU metres. Every fix inherits b, and
once GNSS is gone fixes are the filter's only absolute measurement, so the filter alone can never see it.

A fix measures z = p + b + n (p the vehicle position, n the matcher's error, covariance R). With the prior
p ~ N(p_hat, P) and b ~ N(b_hat, Sigma_b), the joint Kalman update splits the innovation nu = z - b_hat - p_hat
(S = P + R + Sigma_b) between the two: p gains P S^-1, b gains Sigma_b S^-1. So b is learnt when the position
is anchored tighter than the map is georeferenced (the surveyed start, a precise GNSS being fused) and hardly
moves when the position is loose (dead reckoning, fixes alone), with no threshold to tune. The filter keeps only
p, so the update is decoupled (the p-b cross-covariance is dropped): the state takes the fix with R + Sigma_b,
later fixes are corrected by b_hat, and the reported covariance carries Sigma_b, an error common to every fix
that no number of them averages away. With georef_sigma_m = 0 nothing changes (the paper: the map is exact).
Not in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MapOffset", "MapOffsetParams"]


@dataclass(frozen=True)
class MapOffsetParams:
    """georef_sigma_m: the map's georeferencing 1-sigma per axis, m (0: no offset modelled, nothing happens)."""

    georef_sigma_m: float = 0.0


class MapOffset:
    """The estimate of b (module docstring): `b` (2,) m and `cov` (2, 2) m^2, local ENU."""

    def __init__(self, params: MapOffsetParams) -> None:
        self.p = params
        self.b = np.zeros(2)
        self.cov = params.georef_sigma_m ** 2 * np.eye(2)
        self.updates = 0
        self.fixes_applied = 0  # fixes fused into the state since the start

    @property
    def enabled(self) -> bool:
        return self.p.georef_sigma_m > 0.0

    def correct(self, xy: np.ndarray) -> np.ndarray:
        """Map-frame fix positions (..., 2) m -> world frame (the offset taken off)."""
        return np.asarray(xy, dtype=float) - self.b if self.enabled else np.asarray(xy, dtype=float)

    def fix_variance(self) -> float:
        """What a fix's variance (m^2, added in both axes) gains for the state's update: the largest eigenvalue
        of Sigma_b (0 while disabled)."""
        return float(np.linalg.eigvalsh(self.cov)[-1]) if self.enabled else 0.0

    def update(self, innov: np.ndarray, P_xy: np.ndarray, R: np.ndarray, learn: bool = True) -> None:
        """One fix fused into the state; b takes its share when `learn` (False for a relocalisation's jump):
        innov = corrected fix - predicted position (2,) m, P_xy the prior position covariance and R the fix's
        own covariance (2, 2) m^2 (both without Sigma_b)."""
        self.fixes_applied += 1
        finite = np.isfinite(innov).all() and np.isfinite(P_xy).all() and np.isfinite(R).all()
        if not (self.enabled and learn and finite):
            return
        S = P_xy + R + self.cov
        K = np.linalg.solve(S, self.cov).T  # Sigma_b S^-1 (both symmetric)
        self.b = self.b + K @ np.asarray(innov, dtype=float)
        cov = self.cov - K @ self.cov
        self.cov = 0.5 * (cov + cov.T)
        self.updates += 1

    def report_cov(self) -> np.ndarray:
        """What the offset adds to the reported position covariance, m^2 (2, 2): Sigma_b once a fix has been
        fused (before that the state is still in the anchor's frame), zero while disabled."""
        return self.cov if self.enabled and self.fixes_applied else np.zeros((2, 2))
