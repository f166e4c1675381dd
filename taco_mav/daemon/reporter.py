"""How the daemon tells what happens: STATUSTEXT to the autopilot (and so the ground station), rate-limited per
key, and the session's event log (`events.jsonl`). Every handler reports through one `Reporter`."""

from __future__ import annotations

import logging
import math
from typing import Any, Callable

from taco_mav.daemon.eventlog import EventLog
from taco_mav.mavlink import encoders
from taco_mav.mavlink.connection import Link

log = logging.getLogger(__name__)

__all__ = ["Reporter"]


class Reporter:
    """clock: companion monotonic seconds; interval_s: the least time between two STATUSTEXTs of one key. The
    link and the event log are attached when the session opens (`open`); until then STATUSTEXTs go to the log
    only and events nowhere."""

    def __init__(self, clock: Callable[[], float], interval_s: float) -> None:
        self.clock, self.interval_s = clock, interval_s
        self.events = EventLog(None)
        self.link: Link | None = None
        self._last: dict[str, float] = {}

    def open(self, events: EventLog, link: Link) -> None:
        self.events, self.link = events, link

    def close(self) -> None:
        """Flush and close the event log (STATUSTEXTs still go out while the link is open)."""
        self.events.close()

    def event(self, kind: str, **fields: Any) -> None:
        """One line of events.jsonl."""
        self.events.write(kind, **fields)

    def status(self, severity: int, text: str, key: str | None = None) -> None:
        """STATUSTEXT to the autopilot (and the log); `key` rate-limits by the profile's
        output.statustext_interval_s."""
        if key is not None:
            now = self.clock()
            if now - self._last.get(key, -math.inf) < self.interval_s:
                return
            self._last[key] = now
        log.info("STATUSTEXT: %s", text)
        if self.link is not None:
            self.link.send(encoders.statustext(self.link.mav, severity, text))
