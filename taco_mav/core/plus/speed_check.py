"""GNSS ground speed against the camera's (for the GNSS guard): a spoofer that drags the position *and* the
velocity along the direction of travel is invisible to a check against dead reckoning whose own speed error
grows as fast as the drag, but not to the camera, which measures the ground moving past.

The camera's speed carries a scale error (the mount height is known to a few per cent); while the receiver is
trusted that scale is learnt from the pairs (GNSS speed, camera speed), least squares with exponential
forgetting. Afterwards the residual r = v_gnss - s v_cam is averaged over a window: a mean beyond `gate_sigma`
of its own spread (white noise of both, the scale's uncertainty) and beyond `min_gap_mps` flags the receiver.

Speeds m/s, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class SpeedCheckParams:
    """window_s: residuals averaged; scale_tau_s: forgetting time of the scale fit; gate_sigma: flag beyond this
    many sigmas of the window mean ...; min_gap_mps: ... and beyond this; min_speed_mps: slower pairs are not
    used (the camera's relative error grows at a crawl); match_s: a GNSS reading this close to the camera's
    middle time pairs with it; min_pairs: pairs before the scale is trusted; min_window: residuals before a
    window mean counts."""

    window_s: float = 5.0
    scale_tau_s: float = 60.0
    gate_sigma: float = 4.0
    min_gap_mps: float = 0.25
    min_speed_mps: float = 2.0
    match_s: float = 0.2
    min_pairs: int = 20
    min_window: int = 5


class SpeedCheck:
    """Feed GNSS ground speeds (`add_gnss`) and camera speeds (`add_camera`); `add_camera` returns the window's
    mean residual (m/s) when it flags the receiver, else None."""

    def __init__(self, p: SpeedCheckParams = SpeedCheckParams()) -> None:
        self.p = p
        self._gnss: deque[tuple[float, float, float]] = deque(maxlen=200)  # t, speed, sigma
        self._window: deque[tuple[float, float, float]] = deque()  # t, residual, variance
        self._sxy = self._sxx = 0.0
        self._t_fit: float | None = None
        self.pairs = 0
        self.flagged = 0

    @property
    def scale(self) -> float:
        """The learnt camera speed scale (GNSS / camera), 1 until learnt."""
        return self._sxy / self._sxx if self._sxx > 0.0 else 1.0

    def add_gnss(self, t: float, speed: float, sigma: float) -> None:
        """A GNSS ground speed (m/s, 1-sigma m/s) at time t (s)."""
        if math.isfinite(speed) and math.isfinite(sigma):
            self._gnss.append((t, speed, sigma))

    def _gnss_at(self, t: float) -> tuple[float, float] | None:
        near = [(s, sg) for tg, s, sg in self._gnss if abs(tg - t) <= self.p.match_s]
        if not near:
            return None
        return sum(s for s, _ in near) / len(near), max(sg for _, sg in near) / math.sqrt(len(near))

    def add_camera(self, t: float, v_cam: float, sigma_cam: float, trusted: bool) -> float | None:
        """A camera speed (m/s, 1-sigma m/s) at time t (s); trusted: the receiver is in use and unsuspected
        (the scale learns only then)."""
        p = self.p
        g = self._gnss_at(t)
        if g is None or abs(v_cam) < p.min_speed_mps or not math.isfinite(v_cam):
            return None
        v_g, s_g = g
        v_c = abs(v_cam)
        r = v_g - self.scale * v_c
        var = s_g * s_g + (self.scale * sigma_cam) ** 2
        while self._window and t - self._window[0][0] > p.window_s:
            self._window.popleft()
        if trusted and (self.pairs < p.min_pairs or r * r <= 9.0 * var):
            if self._t_fit is not None:
                f = math.exp(-max(t - self._t_fit, 0.0) / p.scale_tau_s)
                self._sxy, self._sxx = f * self._sxy, f * self._sxx
            self._t_fit = t
            self._sxy += v_g * v_c
            self._sxx += v_c * v_c
            self.pairs += 1
        if self.pairs < p.min_pairs:
            return None
        # the scale's own uncertainty: white variance over the effective number of pairs in the fit
        var_scale = var / max(self._sxx, 1e-9)
        self._window.append((t, r, var))
        n = len(self._window)
        if n < p.min_window:
            return None
        mean = sum(x for _, x, _ in self._window) / n
        spread = math.sqrt(sum(v for _, _, v in self._window) / (n * n) + var_scale * v_c * v_c)
        if abs(mean) > max(p.gate_sigma * spread, p.min_gap_mps):
            self.flagged += 1
            return mean
        return None
