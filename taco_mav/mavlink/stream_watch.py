"""Whether the streams the autopilot granted keep arriving at their rate.

An accepted SET_MESSAGE_INTERVAL is a promise, not a delivery: the rate can be changed afterwards on the same
port (a ground station's REQUEST_DATA_STREAM or SRn_ parameters on ArduPilot, a `mavlink stream` command on PX4;
ArduPilot's own example script re-applies its intervals every 5 s for this reason), and an answer misread at
start-up once left the daemon sure of a 40 Hz IMU that came at 1 Hz. `StreamWatch` counts what arrives of the
watched messages (the estimator's inputs) and, every `window_s` (2 s), names those that came at under `fraction` of
their granted rate, so that the daemon asks for them again.

A window in which the link itself went quiet (no message at all for `quiet_s`) is not judged: an outage is the
link watch's business, and asking again into a dead link would only use up the requester's tries."""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class StreamWatch:
    """names: the messages watched; window_s: seconds each judgement covers (companion clock); fraction: a
    stream below fraction x its granted rate is slow; quiet_s: a gap between any two messages longer than this
    leaves the window unjudged."""

    names: tuple[str, ...]
    window_s: float = 2.0
    fraction: float = 0.5
    quiet_s: float = 1.0
    slow_found: int = 0  # slow streams named, all windows
    _counts: dict[str, int] = field(default_factory=dict)
    _granted: dict[str, float] = field(default_factory=dict)  # granted at the window's start: the ones judged
    _since: float | None = None
    _last: float = -math.inf
    _quiet: bool = False

    def arrived(self, kind: str, now: float) -> None:
        """Any message from the autopilot, of type `kind`, at companion time `now` (s)."""
        if now - self._last > self.quiet_s and self._since is not None:
            self._quiet = True
        self._last = now
        if kind in self._counts:
            self._counts[kind] += 1

    def check(self, now: float, granted: dict[str, float]) -> list[tuple[str, float, float]]:
        """At companion time `now` (s), with `granted` (message name -> rate Hz the autopilot accepted): once a
        window is over, the watched streams granted for all of it that came too slowly, as (name, measured Hz,
        granted Hz); then a new window starts."""
        if self._since is not None and now - self._since < self.window_s:
            return []
        slow: list[tuple[str, float, float]] = []
        if self._since is not None and not self._quiet and now - self._last <= self.quiet_s:
            span = now - self._since
            for name, rate in self._granted.items():
                measured = self._counts[name] / span
                if granted.get(name) == rate and measured < self.fraction * rate:
                    slow.append((name, measured, rate))
        self.slow_found += len(slow)
        self._since, self._quiet = now, False
        if self._last == -math.inf:  # nothing heard yet: the silence is counted from here
            self._last = now
        self._granted = {n: r for n, r in granted.items() if n in self.names}
        self._counts = {n: 0 for n in self.names}
        return slow
