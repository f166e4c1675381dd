"""Wheel odometry from cumulative wheel distances (MAVLink WHEEL_DISTANCE): each wheel's distance differenced to a
speed, their mean (carried to the reference point by the yaw rate) the vehicle's forward speed and, with two
wheels at different lateral positions, the yaw rate. A sample that cannot be differenced honestly is refused with
its reason: the first, a repeat or a step back in time (a restart of the differencing), a change in the number of
wheels, non-finite values, or a distance step implying an impossible speed (a jump).

Body FRD lateral positions (y right, metres), as ArduPilot's WENC_POS_Y; speeds m/s forward positive; yaw rate
ENU rad/s (counter-clockwise positive); times autopilot seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["WheelMotion", "WheelOdometry"]


@dataclass(frozen=True)
class WheelMotion:
    """The motion between two wheel samples at t0 and t1 (autopilot s): speed, m/s forward, at the reference
    point (y = 0); yaw_rate, ENU rad/s, or None without two wheels apart; wheel_speeds, m/s, each wheel's."""

    t0: float
    t1: float
    speed: float
    yaw_rate: float | None
    wheel_speeds: tuple[float, ...]

    @property
    def t_mid(self) -> float:
        """The middle of the interval, autopilot s: the time the mean speed belongs to."""
        return 0.5 * (self.t0 + self.t1)


class WheelOdometry:
    """Difference successive samples (`add`). pos_y_m: each wheel's lateral position, body FRD metres (first two
    wheels; more are averaged into the speed only); max_speed_mps: a step implying more is a jump."""

    def __init__(self, pos_y_m: Sequence[float], max_speed_mps: float) -> None:
        self.pos_y = tuple(float(y) for y in pos_y_m)
        self.max_speed = float(max_speed_mps)
        self._last: tuple[float, tuple[float, ...]] | None = None
        self.last_t = -math.inf  # autopilot s of the last sample taken (accepted or not)

    def set_pos_y(self, pos_y_m: Sequence[float]) -> None:
        """The wheels' lateral positions as the autopilot reports them (WENC_POS_Y, WENC2_POS_Y), FRD metres."""
        self.pos_y = tuple(float(y) for y in pos_y_m)

    def add(self, t: float, distances: Sequence[float]) -> WheelMotion | str:
        """One sample: t autopilot s, distances cumulative metres per wheel. The motion since the previous
        sample, or why there is none: "first", "repeat", "backstep", "count", "nonfinite", "jump" (the sample
        after a refusal starts the differencing again)."""
        d = tuple(float(x) for x in distances)
        if not d or not math.isfinite(t) or not all(math.isfinite(x) for x in d):
            return "nonfinite"
        last, self._last = self._last, (t, d)
        self.last_t = t
        if last is None:
            return "first"
        t0, d0 = last
        if t == t0:
            self._last = last
            return "repeat"
        if t < t0:
            return "backstep"
        if len(d0) != len(d):
            return "count"
        dt = t - t0
        speeds = tuple((b - a) / dt for a, b in zip(d0, d))
        if max(abs(v) for v in speeds) > self.max_speed:
            return "jump"
        yaw = self._yaw_rate(speeds)
        mean = sum(speeds) / len(speeds)
        if yaw is not None:  # each wheel moves at v - w_frd y: the mean wheel's y carried to the reference point
            y_mean = sum(self.pos_y[:2]) / 2.0
            mean = sum(speeds[:2]) / 2.0 - yaw * y_mean  # w_enu = -w_frd
        return WheelMotion(t0, t, mean, yaw, speeds)

    def _yaw_rate(self, speeds: tuple[float, ...]) -> float | None:
        """ENU yaw rate from the first two wheels, rad/s: v_i = v - w_frd y_i, so w_frd = (v_a - v_b) / (y_b -
        y_a); None with one wheel or two at the same y."""
        if len(speeds) < 2 or len(self.pos_y) < 2:
            return None
        ya, yb = self.pos_y[0], self.pos_y[1]
        if abs(yb - ya) < 1e-3:
            return None
        return -(speeds[0] - speeds[1]) / (yb - ya)
