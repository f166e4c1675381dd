"""Stationary detection for zero-velocity updates (taco+, not in the paper).

The IMU alone cannot tell a stop from a smooth cruise: at constant velocity a rover on smooth asphalt (and
SITL's rover, whose IMU has no vibration) measures exactly what a parked one does. The detector therefore only
says "IMU still"; the Localiser combines it with what else it knows (its own speed, the autopilot's drive
command). The IMU is still when, over the last `window_s` seconds of samples:
- the largest gyro rate stays below `gyro_max` (rad/s),
- the specific force varies by less than `accel_std_max` (m/s^2: the root of the summed per-axis variances,
  so horizontal vibration counts as much as vertical; an idling engine shakes it less than driving does),
- and the mean gravity-compensated forward acceleration, less the caller's accelerometer-bias estimate, is
  within `accel_mean_max` (m/s^2): a smooth, steady acceleration has no spread at all, but it is not a stop.
"""

from __future__ import annotations

import math
from collections import deque


class StationaryDetector:
    """Feed every IMU sample; `still(bias)` answers for the window that ends at the last sample."""

    def __init__(self, window_s: float, gyro_max: float, accel_std_max: float, accel_mean_max: float = math.inf) -> None:
        self.window_s = window_s
        self.gyro_max = gyro_max
        self.accel_std_max = accel_std_max
        self.accel_mean_max = accel_mean_max
        # per sample, in parallel deques (C-level max / sum over them): t, specific force FRD, |omega|, level
        # forward acceleration
        self._t: deque[float] = deque(maxlen=4096)
        self._f: deque[tuple[float, float, float]] = deque(maxlen=4096)
        self._g: deque[float] = deque(maxlen=4096)
        self._a: deque[float] = deque(maxlen=4096)

    def add(self, t: float, accel: tuple[float, float, float], gyro: tuple[float, float, float],
            accel_fwd: float = 0.0) -> None:
        """t: seconds; accel: specific force, m/s^2; gyro: rad/s (any body frame); accel_fwd: gravity-compensated
        forward acceleration in the level frame, m/s^2."""
        gx, gy, gz = gyro
        ts = self._t
        ts.append(t)
        self._f.append(tuple(accel))
        # |omega| summed left to right, as sum() over the squares did on Python 3.11 (3.12's sum compensates)
        self._g.append(math.sqrt(gx * gx + gy * gy + gz * gz))
        self._a.append(accel_fwd)
        start = t - self.window_s
        while ts and ts[0] < start:
            ts.popleft()
            self._f.popleft()
            self._g.popleft()
            self._a.popleft()

    @property
    def stationary(self) -> bool:
        """Still with a zero accelerometer-bias estimate (see `still`)."""
        return self.still(0.0)

    def still(self, accel_bias: float = 0.0) -> bool:
        """accel_bias: the forward accelerometer bias estimate, m/s^2 (what a still IMU reads forward)."""
        ts = self._t
        if len(ts) < 3 or ts[-1] - ts[0] < 0.8 * self.window_s:
            return False
        if max(self._g) > self.gyro_max:
            return False
        n = len(ts)
        if abs(sum(self._a) / n - accel_bias) > self.accel_mean_max:
            return False
        var = 0.0
        f = self._f
        for axis in range(3):
            mean = sum(v[axis] for v in f) / n
            var += sum((v[axis] - mean) ** 2 for v in f) / (n - 1)
        return math.sqrt(var) <= self.accel_std_max
