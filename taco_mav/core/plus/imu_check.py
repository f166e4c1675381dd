"""The closed-loop safety guard (taco+, not in the paper): the estimate cross-checked against the IMU alone.

An autopilot steers by what we send; an estimate that has lost the vehicle's motion while reporting a small
1-sigma makes it run away. Two independent accounts of the motion since the last accepted camera fix are
kept side by side:
- the estimate (UKF + preintegrator, with zero-velocity updates, speed-error feedback and everything else
  that can go wrong), and
- the unaided track: the forward acceleration (less the accelerometer bias known at the fix) integrated
  twice along the compass heading, from the estimate's position and speed at that fix, nothing else.

The unaided track's own 1-sigma grows as sigma_v0 tau + (sigma_b + accel_sigma) tau^2 / 2 (the speed and bias
uncertainty at the fix, and a white-ish accelerometer error), tau the time since the fix. When the two tracks
disagree by more than k times their combined 1-sigma (and at least `floor_m`), one of them is wrong and we
cannot say which: the Localiser then keeps its reported horizontal variance at least the disagreement squared,
so the accuracy the autopilot sees covers the error whichever track is right, and a covariance trigger asks
the camera. The guard also tells the Localiser to distrust its zero-velocity detector for `zupt_holdoff_s`.

World frame ENU metres, headings ENU radians, times seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Disagreement:
    """A check's verdict. distance_m: |estimate - unaided| (ENU m); sigma_m: their combined 1-sigma, metres;
    tau_s: time since the reference fix; speed_gap_mps: estimate speed minus unaided speed."""

    distance_m: float
    sigma_m: float
    tau_s: float
    speed_gap_mps: float


class UnaidedTrack:
    """IMU-only dead reckoning since the last reset (an accepted fix).

    k: disagreement threshold in combined sigmas; floor_m: never flag less than this, metres; accel_sigma:
    1-sigma forward acceleration error of the IMU alone, m/s^2 (beside the bias uncertainty at the reset)."""

    def __init__(self, k: float, floor_m: float, accel_sigma: float) -> None:
        self.k, self.floor_m, self.accel_sigma = k, floor_m, accel_sigma
        self.t0 = math.nan
        self.x = self.y = 0.0
        self.v = 0.0
        self.bias = 0.0
        self.sigma_v0 = self.sigma_b = 0.0
        self.sigma_xy0 = 0.0
        self.t = math.nan

    @property
    def started(self) -> bool:
        return math.isfinite(self.t0)

    def reset(self, t: float, xy: tuple[float, float], speed: float, bias: float, sigma_xy: float, sigma_v: float,
              sigma_b: float) -> None:
        """Start again from the estimate at time t (s): position ENU m, forward speed m/s, forward accelerometer
        bias m/s^2, and their 1-sigmas (m, m/s, m/s^2)."""
        self.t0 = self.t = t
        self.x, self.y = xy
        self.v, self.bias = speed, bias
        self.sigma_xy0, self.sigma_v0, self.sigma_b = sigma_xy, sigma_v, sigma_b

    def add(self, t: float, accel_fwd: float, theta: float, allow_reverse: bool) -> None:
        """One IMU sample at time t (s): level forward acceleration m/s^2, compass heading ENU rad."""
        if not math.isfinite(self.t0):  # not started (the property, inline: 100 Hz)
            return
        dt = t - self.t
        if dt <= 0.0:
            return
        self.t = t
        v1 = self.v + (accel_fwd - self.bias) * dt
        if not allow_reverse and v1 < 0.0:  # max(v1, 0.0), the same value for -0.0 and NaN too
            v1 = 0.0
        step = 0.5 * (self.v + v1) * dt
        self.v = v1
        self.x += step * math.cos(theta)
        self.y += step * math.sin(theta)

    def tau(self) -> float:
        """Seconds since the reset (0 before the first)."""
        return max(self.t - self.t0, 0.0) if self.started else 0.0

    def sigma(self) -> float:
        """The unaided track's 1-sigma position error relative to the estimate at the reset, metres."""
        tau = self.tau()
        return self.sigma_v0 * tau + 0.5 * (self.sigma_b + self.accel_sigma) * tau * tau

    def sigma_speed(self) -> float:
        """The unaided track's 1-sigma speed error, m/s: sigma_v0 + (sigma_b + accel_sigma) tau, the derivative of
        `sigma()`; after a long time without fixes its speed is worth little."""
        return self.sigma_v0 + (self.sigma_b + self.accel_sigma) * self.tau()

    def check(self, xy: tuple[float, float], speed: float, sigma_est_m: float) -> Disagreement | None:
        """Compare the estimate (position ENU m, speed m/s, its 1-sigma m) with the unaided track; the
        disagreement when it exceeds the threshold, else None."""
        if not self.started:
            return None
        d = math.hypot(xy[0] - self.x, xy[1] - self.y)
        s = math.hypot(self.sigma(), sigma_est_m)
        if d > max(self.k * s, self.floor_m):
            return Disagreement(d, s, self.t - self.t0, speed - self.v)
        return None
