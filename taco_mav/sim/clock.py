"""The simulated autopilot's clock: seconds since boot, running at `speed` times real time, or, in lockstep,
moved forward only by the player (so a slow companion stretches wall time instead of losing messages).

Thread-safe: the player advances it, the receiver and an in-process companion read it.
"""

from __future__ import annotations

import threading
import time
from typing import Callable

__all__ = ["SimClock"]


class SimClock:
    """Autopilot time, seconds since boot. Starts at `boot_offset_s` when created.

    speed: real-time factor (> 0). While `hold()` is in force (lockstep playback) the clock reads exactly the
    last value given to `advance_to`; otherwise it runs from that value at `speed` x wall time. `simulated`: a
    companion on this clock (`daemon.clock.CompanionClock`) waits on it in short wall-time steps.
    """

    simulated = True

    def __init__(self, speed: float = 1.0, boot_offset_s: float = 0.0,
                 wall: Callable[[], float] = time.monotonic) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be positive, got {speed}")
        self.speed = float(speed)
        self._wall = wall
        self._lock = threading.Lock()
        self._anchor_wall = wall()
        self._anchor_t = float(boot_offset_s)
        self._held = False

    def now(self) -> float:
        """Autopilot seconds since boot."""
        with self._lock:
            if self._held:
                return self._anchor_t
            return self._anchor_t + (self._wall() - self._anchor_wall) * self.speed

    __call__ = now

    def hold(self) -> None:
        """Freeze the clock at its current reading; from now on only `advance_to` moves it (lockstep)."""
        t = self.now()
        with self._lock:
            self._anchor_t, self._held = t, True

    def release(self) -> None:
        """Let the clock run again at `speed` from its current reading."""
        t = self.now()
        with self._lock:
            self._anchor_t, self._anchor_wall, self._held = t, self._wall(), False

    def advance_to(self, t: float) -> None:
        """Held clock: set it to t (never backwards). Running clock: re-anchor so it reads t now."""
        with self._lock:
            if self._held:
                self._anchor_t = max(self._anchor_t, float(t))
            else:
                self._anchor_t, self._anchor_wall = float(t), self._wall()

    def wall_until(self, t: float) -> float:
        """Wall seconds until a running clock reaches t (0 when past or held)."""
        with self._lock:
            if self._held:
                return 0.0
            now = self._anchor_t + (self._wall() - self._anchor_wall) * self.speed
        return max(0.0, (t - now) / self.speed)
