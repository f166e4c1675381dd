"""Companion clock -> autopilot clock. The filter runs on autopilot time (IMU time_usec / time_boot_ms); camera
frames are stamped on the companion's monotonic clock and mapped across with the offset kept here.

autopilot_s = companion_s + offset. Sources, best first:
- TIMESYNC round trips (we send tc1 = 0, ts1 = our monotonic ns; the autopilot answers tc1 = its clock in ns):
  offset = tc1 - (ts1 + t_reply) / 2; of recent samples the one with the shortest round trip wins.
- SYSTEM_TIME.time_boot_ms on arrival (biased late by the link latency), used when TIMESYNC goes unanswered.
- IMU timestamps on arrival (same bias), until anything better is heard.
For the arrival-time sources the largest recent (autopilot - arrival) is kept: latency only ever makes the
offset look smaller.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from typing import Callable

log = logging.getLogger(__name__)

_PRIORITY = {"timesync": 3, "system_time": 2, "imu": 1}


class ClockMap:
    """Offset between the companion's monotonic clock and the autopilot's clock, seconds.

    clock: the companion clock (seconds, monotonic); max_rtt_s: TIMESYNC round trips longer than this are
    ignored; window: samples kept per source; stale_s: a source not heard for this long gives way to lower ones.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, max_rtt_s: float = 0.5, window: int = 20,
                 stale_s: float = 5.0) -> None:
        self.clock = clock
        self.max_rtt_s = max_rtt_s
        self.stale_s = stale_s
        self._samples: dict[str, deque[tuple[float, float, float]]] = {k: deque(maxlen=window) for k in _PRIORITY}
        self.last_rtt_s: float | None = None

    def reset(self) -> None:
        """Forget everything (autopilot reboot)."""
        for q in self._samples.values():
            q.clear()
        self.last_rtt_s = None

    # ---------------------------------------------------------------- samples
    def request_ns(self) -> int:
        """ts1 for an outgoing TIMESYNC request: our clock in ns."""
        return int(self.clock() * 1e9)

    def on_timesync_reply(self, tc1_ns: int, ts1_ns: int) -> bool:
        """A TIMESYNC answer to one of our requests; False when it is implausible (ignored)."""
        now = self.clock()
        sent = ts1_ns * 1e-9
        rtt = now - sent
        if tc1_ns <= 0 or not 0.0 <= rtt <= self.max_rtt_s:
            return False
        self.last_rtt_s = rtt
        self._samples["timesync"].append((now, tc1_ns * 1e-9 - (sent + now) / 2.0, rtt))
        return True

    def on_system_time(self, time_boot_ms: int) -> None:
        """SYSTEM_TIME arrived now."""
        if time_boot_ms > 0:
            now = self.clock()
            self._samples["system_time"].append((now, time_boot_ms * 1e-3 - now, 0.0))

    def on_autopilot_time(self, t_autopilot: float) -> None:
        """A timestamped input (IMU) arrived now."""
        now = self.clock()
        self._samples["imu"].append((now, t_autopilot - now, 0.0))

    # ---------------------------------------------------------------- queries
    @property
    def source(self) -> str | None:
        """The source the offset currently comes from ("timesync", "system_time", "imu") or None."""
        now = self.clock()
        for name in sorted(_PRIORITY, key=_PRIORITY.get, reverse=True):
            q = self._samples[name]
            if q and now - q[-1][0] <= self.stale_s:
                return name
        for name in sorted(_PRIORITY, key=_PRIORITY.get, reverse=True):
            if self._samples[name]:
                return name
        return None

    @property
    def offset(self) -> float | None:
        """autopilot_s - companion_s, or None before any sample."""
        name = self.source
        if name is None:
            return None
        q = self._samples[name]
        if name == "timesync":
            return min(q, key=lambda s: s[2])[1]
        return max(s[1] for s in q)

    def to_autopilot(self, t_companion: float) -> float | None:
        """Companion monotonic seconds -> autopilot seconds (None before any sample)."""
        off = self.offset
        return None if off is None else t_companion + off

    def to_companion(self, t_autopilot: float) -> float | None:
        """Autopilot seconds -> companion monotonic seconds (None before any sample)."""
        off = self.offset
        return None if off is None else t_autopilot - off

    def now_autopilot(self) -> float | None:
        """The autopilot clock now, seconds (None before any sample)."""
        return self.to_autopilot(self.clock())
