"""A fixed-rate schedule on an absolute grid: due times t0 + k / rate never drift with loop jitter, and a
late loop skips missed slots instead of bursting to catch up."""

from __future__ import annotations


class Periodic:
    """Due times on the grid start + k * period (seconds, any monotonic clock)."""

    def __init__(self, rate_hz: float, start: float) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate must be positive, got {rate_hz}")
        self.period = 1.0 / rate_hz
        self.next_due = start
        self.skipped = 0

    def due(self, now: float) -> bool:
        """True once per slot when `now` has reached it; advances to the next slot after `now`."""
        if now < self.next_due:
            return False
        self.next_due += self.period
        if self.next_due <= now:  # the loop was late by more than a period: skip, do not burst
            missed = int((now - self.next_due) // self.period) + 1
            self.skipped += missed
            self.next_due += missed * self.period
        return True

    def wait(self, now: float) -> float:
        """Seconds until the next slot (0 when due)."""
        return max(0.0, self.next_due - now)
