"""Stationary detection for zero-velocity updates (taco+, issue 7).

The vehicle is taken as stationary when, over the last `window_s` seconds of IMU samples, the largest gyro
rate stays below `gyro_max` (rad/s) and the specific force varies by less than `accel_std_max` (m/s^2: the
root of the summed per-axis variances, so horizontal vibration counts as much as vertical): an engine idling
on a stopped rover shakes the accelerometer less than driving does.
"""

from __future__ import annotations

import math
from collections import deque


class StationaryDetector:
    """Feed every IMU sample; `stationary` answers for the window that ends at the last sample."""

    def __init__(self, window_s: float, gyro_max: float, accel_std_max: float) -> None:
        self.window_s = window_s
        self.gyro_max = gyro_max
        self.accel_std_max = accel_std_max
        self._samples: deque[tuple[float, tuple[float, float, float], float]] = deque(maxlen=4096)  # t, f, |omega|

    def add(self, t: float, accel: tuple[float, float, float], gyro: tuple[float, float, float]) -> None:
        """t: seconds; accel: specific force, m/s^2; gyro: rad/s (any body frame)."""
        self._samples.append((t, tuple(accel), math.sqrt(sum(g * g for g in gyro))))
        while self._samples and self._samples[0][0] < t - self.window_s:
            self._samples.popleft()

    @property
    def stationary(self) -> bool:
        s = self._samples
        if len(s) < 3 or s[-1][0] - s[0][0] < 0.8 * self.window_s:
            return False
        if max(g for _, _, g in s) > self.gyro_max:
            return False
        n = len(s)
        var = 0.0
        for axis in range(3):
            mean = sum(f[axis] for _, f, _ in s) / n
            var += sum((f[axis] - mean) ** 2 for _, f, _ in s) / (n - 1)
        return math.sqrt(var) <= self.accel_std_max
