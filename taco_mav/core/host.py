"""What the Localiser's parts see of it: `Host`, the narrow interface its mode (paper.py, plus/mode.py), its GNSS
fusion (gnss/fusion.py) and taco+'s parts (plus/) are given, instead of the Localiser class itself. The Localiser
(localiser.py) satisfies it; the parts import this module, never the Localiser, so nothing imports back up.

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.frames import FixOutcome, Tick
from taco_mav.core.gnss.guard import GnssGuard
from taco_mav.core.params import LocaliserParams
from taco_mav.core.preintegration import Preintegrator
from taco_mav.core.types import Estimate, FixQuery, MatchResult
from taco_mav.core.ukf import PlanarUkf

__all__ = ["GnssStatus", "Host"]


class GnssStatus(Protocol):
    """The real GNSS as taco+'s trigger and camera-speed check see it."""

    guard: GnssGuard | None  # None before the first reading

    @property
    def in_use(self) -> bool:
        """A reading accepted within the guard's gap_s of now."""


class Host(Protocol):
    """The filter and the answer plumbing of the Localiser a part serves."""

    p: LocaliserParams
    t: float  # the IMU clock, autopilot s
    frame_dt: float  # filter frame period, s
    pre: Preintegrator
    ukf: PlanarUkf
    history: deque[Tick]  # the frames a late answer rewinds to, oldest first
    terms: ErrorTerms  # the error model's terms at the last frame
    last_fix_t: float  # capture time of the last answered query, s

    @property
    def gnss(self) -> GnssStatus:
        """The real-GNSS fusion's state."""

    def filter_estimate(self) -> Estimate:
        """The filter's own estimate (before the mode's reported accuracy)."""

    def widen(self, s: float) -> None:
        """Add s^2 (m^2) to both position variances."""

    def replay_after(self, base: Tick) -> None:
        """Replay the frames after `base` from the filter's current state (which is base's)."""

    def settle(self, tick: Tick) -> None:
        """Store the state on `tick` after measurement updates there and reset the anchor window."""

    def take_pending(self, query_id: int, results: Sequence[MatchResult | None]) -> FixQuery | FixOutcome:
        """The in-flight query these results answer, or the outcome when they answer none or hold nothing."""

    def fix_sigmas(self, w: float, anisotropic: bool | None = None) -> tuple[float, float]:
        """Body-frame fix sigmas (forward, lateral), metres, from the match weight."""

    def capture_tick(self, q: FixQuery) -> Tick | None:
        """The history frame a fix for `q` applies at."""

    def fuse(self, tick: Tick | None, xy: np.ndarray, s_f: float, s_l: float,
             heading: tuple[float, float] | None = None) -> float:
        """Apply a fix at `tick` (rewind, update, replay); returns its NIS."""

    def log(self, outcome: FixOutcome) -> FixOutcome:
        """Record what became of an answer; returns it."""
