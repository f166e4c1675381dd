"""Reading named autopilot parameters once (PARAM_REQUEST_READ, answered by PARAM_VALUE), retried while any is
unanswered, given up after a few tries. Driven by the daemon loop: `tick(now, ...)` asks for what is missing,
`on_message(msg)` takes the answers. The GPS check (requests.ParamCheck) has its own reasons to stay apart (which
names stand for which instance, its warnings); this one only reads values, e.g. WENC_POS_Y / WENC2_POS_Y."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable

log = logging.getLogger(__name__)

__all__ = ["ParamRead"]


@dataclass
class ParamRead:
    """Read each of `names` once: `values` name -> value as answered; `done` when all are in or after `tries`
    rounds `retry_s` (companion s) apart."""

    send: Callable[[Any], None]
    mav: Any
    names: tuple[str, ...]
    retry_s: float = 2.0
    tries: int = 3
    values: dict[str, float] = field(default_factory=dict)
    _tries: int = 0
    _next: float = -math.inf

    @property
    def done(self) -> bool:
        return set(self.names) <= set(self.values) or self._tries >= self.tries

    @property
    def complete(self) -> bool:
        """Every name answered."""
        return set(self.names) <= set(self.values)

    def tick(self, now: float, target_system: int, target_component: int) -> None:
        """Ask for the names not yet answered when a round is due at companion time `now` (s)."""
        if self.done or now < self._next or not target_system:
            return
        self._next = now + self.retry_s
        self._tries += 1
        for name in self.names:
            if name not in self.values:
                self.send(self.mav.param_request_read_encode(target_system, target_component, name.encode(), -1))
        if self._tries >= self.tries and not self.complete:
            log.warning("no answer to PARAM_REQUEST_READ %s", ", ".join(n for n in self.names if n not in self.values))

    def on_message(self, msg: Any) -> tuple[str, float] | None:
        """A PARAM_VALUE: (name, value) when it answers one of ours for the first time with a finite value."""
        if msg.get_type() != "PARAM_VALUE":
            return None
        pid = msg.param_id.decode() if isinstance(msg.param_id, bytes) else str(msg.param_id)
        pid = pid.rstrip("\x00")
        value = float(msg.param_value)
        if pid not in self.names or pid in self.values or not math.isfinite(value):
            return None
        self.values[pid] = value
        log.info("%s=%g", pid, value)
        return pid, value
