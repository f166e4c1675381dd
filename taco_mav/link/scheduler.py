"""A fixed-rate schedule on an absolute grid: due times start + k / rate never drift with loop jitter (k is an
integer, so no rounding accumulates), and a late loop skips missed slots instead of bursting to catch up."""

from __future__ import annotations

import math


class Periodic:
    """Due times on the grid start + k * period (seconds, any monotonic clock)."""

    def __init__(self, rate_hz: float, start: float) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate must be positive, got {rate_hz}")
        self.period = 1.0 / rate_hz
        self.start = start
        self._k = 0
        self.skipped = 0

    @property
    def next_due(self) -> float:
        return self.start + self._k * self.period

    def due(self, now: float) -> bool:
        """True once per slot when `now` has reached it; advances to the first slot after `now`."""
        if now < self.next_due - 1e-9:
            return False
        k_now = int(math.floor((now - self.start) / self.period + 1e-9))  # the slot `now` is in
        self.skipped += max(0, k_now - self._k)
        self._k = k_now + 1
        return True

    def wait(self, now: float) -> float:
        """Seconds until the next slot (0 when due)."""
        return max(0.0, self.next_due - now)
