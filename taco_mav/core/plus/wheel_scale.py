"""The wheels' scale error learnt from the camera's fixes (taco+, plus/wheel_speed.py).

The wheel speed is the true speed divided by a scale s near 1 (a wheel radius a few per cent off: tyre pressure,
load, wear). With the wheels steering the speed estimate, the position between two accepted fixes runs ahead or
behind by (s - s_hat) times the displacement W driven on the wheels' raw speed since the first of them, so the
second fix's innovation nu measures the scale error along W: (nu . u) / |W|, u = W / |W|, with variance
u^T S u / |W|^2, S the fix's innovation covariance. A scalar Kalman filter keeps s and its variance (a slow random
walk per kilometre between fixes) and takes one such measurement per accepted fix over at least
wheels.scale_min_span_m. Beside it, sigma_s^2 W W^T is the covariance the unknown rest of the scale puts on the
position since the last fix (a consider term, as speed_scale.py's for the camera).

Lengths metres (ENU), scale dimensionless.
"""

from __future__ import annotations

import math

import numpy as np

from taco_mav.core.frames import Tick

__all__ = ["WheelScale"]


class WheelScale:
    """s (true speed = s x wheel speed) and its variance; `track` the ENU displacement driven on the wheels' raw
    speed, `pinned` where it stood at the last accepted fix (or the start, whose position is known)."""

    def __init__(self, sigma: float, walk_per_sqrt_km: float, min_span_m: float) -> None:
        self.s = 1.0
        self.var = float(sigma) ** 2
        self.walk2_per_m = float(walk_per_sqrt_km) ** 2 / 1000.0  # scale variance added per metre driven
        self.min_span_m = float(min_span_m)
        self.track = np.zeros(2)
        self.pinned: np.ndarray | None = np.zeros(2)  # the start's position is known: pinned there
        self.learnt = 0  # fixes that measured the scale

    @property
    def sigma(self) -> float:
        """The scale's 1-sigma (dimensionless)."""
        return math.sqrt(self.var)

    def advance(self, tick: Tick, distance_raw: float, heading_mid: float) -> None:
        """The frame moved distance_raw metres (signed) on the wheels' raw speed along heading_mid (ENU rad);
        the running total is kept on the tick (a late fix measures at its capture)."""
        if distance_raw:
            self.track = self.track + distance_raw * np.array([math.cos(heading_mid), math.sin(heading_mid)])
            self.var += self.walk2_per_m * abs(distance_raw)
        tick.wheel_track = (float(self.track[0]), float(self.track[1]))

    def span(self, tick: Tick) -> np.ndarray | None:
        """W: the raw wheel displacement from the last accepted fix to tick's end, ENU m (None before a fix or
        without wheels on the tick)."""
        if self.pinned is None or tick.wheel_track is None:
            return None
        return np.array(tick.wheel_track) - self.pinned

    def covariance(self) -> np.ndarray | None:
        """sigma_s^2 W W^T from the last accepted fix to now, ENU m^2 (2x2), or None before a fix."""
        if self.pinned is None:
            return None
        w = self.track - self.pinned
        return self.var * np.outer(w, w)

    def covariance_at(self, tick: Tick) -> np.ndarray | None:
        """sigma_s^2 W W^T to the history frame `tick`, ENU m^2 (2x2), or None."""
        w = self.span(tick)
        return None if w is None else self.var * np.outer(w, w)

    def fix(self, tick: Tick, innovation: np.ndarray, S: np.ndarray) -> None:
        """An accepted fix at `tick` with innovation `innovation` (fix less prediction, ENU m) of covariance S
        (m^2, 2x2): one scale measurement when the span since the last is long enough, then the pin moves here."""
        w = self.span(tick)
        if w is not None:
            n = float(np.linalg.norm(w))
            if n >= max(self.min_span_m, 1e-6):
                u = w / n
                z = float(innovation @ u) / n
                r = float(u @ S @ u) / (n * n)
                k = self.var / (self.var + r)
                self.s += k * z
                self.var *= 1.0 - k
                self.learnt += 1
        if tick.wheel_track is not None:
            self.pinned = np.array(tick.wheel_track)
