"""The companion clock the daemon runs on: this machine's monotonic clock, or a simulator's (`sim.clock.SimClock`),
which says so itself (`simulated`): it may run faster than wall time, or stand still between a lockstep
player's steps, so the daemon waits on it in short wall-time steps and reads it again."""

from __future__ import annotations

import time
from typing import Protocol

__all__ = ["MONOTONIC", "CompanionClock", "MonotonicClock"]


class CompanionClock(Protocol):
    """clock() -> companion seconds (monotonic); simulated: a simulator's clock, not wall time."""

    simulated: bool

    def __call__(self) -> float: ...


class MonotonicClock:
    """This machine's monotonic clock (`time.monotonic`), seconds."""

    simulated = False

    def __call__(self) -> float:
        return time.monotonic()


MONOTONIC = MonotonicClock()
