"""Reading named autopilot parameters once (PARAM_REQUEST_READ, answered by PARAM_VALUE), retried while any is
unanswered, given up after a few tries. One value may go by several names across firmware (ArduPilot 4.6 renamed
GPS_TYPE to GPS1_TYPE): all are asked for and the first answer counts. Driven by the daemon loop: `tick(now, ...)`
asks for what is missing, `on_message(msg)` takes the answers. The daemon reads WENC_POS_Y / WENC2_POS_Y with it,
and the GPS check (requests.ParamCheck) its instances' types and antenna offsets."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["ParamRead"]


class ParamRead:
    """Read each value of `names` once. An entry is a parameter name, or the names one value goes by (newest
    firmware's first: ("GPS1_TYPE", "GPS_TYPE")); the value is kept under the first (its key). `values`: key ->
    value as answered; `answered_by`: key -> the name that answered; `done` when all are in or after `tries`
    rounds `retry_s` (companion s) apart."""

    def __init__(self, send: Callable[[Any], None], mav: Any, names: Sequence[str | tuple[str, ...]],
                 retry_s: float = 2.0, tries: int = 3) -> None:
        self.send, self.mav, self.retry_s, self.tries = send, mav, retry_s, tries
        self.groups: dict[str, tuple[str, ...]] = {}  # key -> every name it goes by
        for entry in names:
            group = (entry,) if isinstance(entry, str) else tuple(entry)
            self.groups[group[0]] = group
        self._key_of = {name: key for key, group in self.groups.items() for name in group}
        self.values: dict[str, float] = {}
        self.answered_by: dict[str, str] = {}
        self._tries = 0
        self._next = -math.inf

    @property
    def complete(self) -> bool:
        """Every value answered."""
        return len(self.values) == len(self.groups)

    @property
    def done(self) -> bool:
        return self.complete or self._tries >= self.tries

    @property
    def missing(self) -> list[str]:
        """The keys not answered yet."""
        return [key for key in self.groups if key not in self.values]

    def tick(self, now: float, target_system: int, target_component: int) -> list[str]:
        """Ask for every name of the values not yet answered when a round is due at companion time `now` (s).
        Returns the keys still unanswered when this round was the last (the caller says what that costs), else
        an empty list."""
        if self.done or now < self._next or not target_system:
            return []
        self._next = now + self.retry_s
        self._tries += 1
        for key in self.missing:
            for name in self.groups[key]:
                self.send(self.mav.param_request_read_encode(target_system, target_component, name.encode(), -1))
        return self.missing if self._tries >= self.tries else []

    def on_message(self, msg: Any) -> tuple[str, float] | None:
        """A PARAM_VALUE: (key, value) when it answers one of ours for the first time with a finite value (a
        non-finite one is logged and asked for again)."""
        if msg.get_type() != "PARAM_VALUE":
            return None
        pid = msg.param_id.decode() if isinstance(msg.param_id, bytes) else str(msg.param_id)
        pid = pid.rstrip("\x00")
        key = self._key_of.get(pid)
        if key is None or key in self.values:
            return None
        value = float(msg.param_value)
        if not math.isfinite(value):
            log.warning("PARAM_VALUE %s is not finite (%r): ignored", pid, value)
            return None
        self.values[key] = value
        self.answered_by[key] = pid
        log.info("%s=%g", pid, value)
        return key, value
