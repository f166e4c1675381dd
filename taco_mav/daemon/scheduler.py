"""A fixed-rate schedule on an absolute grid: due times start + k / rate never drift with loop jitter (k is an
integer, so no rounding accumulates), and a late loop skips missed slots instead of bursting to catch up.

`AutopilotPeriodic` keeps a rate in the AUTOPILOT's time while scheduling on the companion clock: its grid runs
at rate x speed, speed being autopilot seconds per companion second (`timesync.ClockMap.speed`: 1 on a real
vehicle, N beside a simulator N times faster than real time, None while unknown: wall pacing)."""

from __future__ import annotations

import math
from typing import Callable


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

    def restart(self, start: float) -> None:
        """Begin the grid again at `start` (a session that opens later than the schedule was made)."""
        self.start, self._k = start, 0

    def wait(self, now: float) -> float:
        """Seconds until the next slot (0 when due)."""
        return max(0.0, self.next_due - now)

    def set_rate(self, rate_hz: float) -> None:
        """Change the rate from the next slot on: the grid is re-anchored at the last slot (sent or skipped), so
        a change neither bursts nor drops a slot by itself."""
        if rate_hz <= 0:
            raise ValueError(f"rate must be positive, got {rate_hz}")
        period = 1.0 / rate_hz
        if period == self.period:
            return
        if self._k > 0:
            self.start += (self._k - 1) * self.period
            self._k = 1
        self.period = period


class AutopilotPeriodic(Periodic):
    """`rate_hz` in autopilot time: before each check the grid's companion-clock rate becomes rate_hz x speed()
    (speed: autopilot s per companion s, None = unknown: rate_hz on the companion clock)."""

    def __init__(self, rate_hz: float, start: float, speed: Callable[[], float | None]) -> None:
        super().__init__(rate_hz, start)
        self.rate_hz, self.speed = rate_hz, speed

    def due(self, now: float) -> bool:
        self.set_rate(self.rate_hz * (self.speed() or 1.0))
        return super().due(now)
