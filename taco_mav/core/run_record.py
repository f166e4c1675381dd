"""What an offline run keeps of the Localiser (`Localiser(record=True)`): the online track at every frame, the
queries and what became of their answers, and the Pose2 smoother's inputs (the frames' states and increments,
their odometry sigmas and the fixes), restated whenever a rewind changes a frame. The live daemon keeps none.

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from taco_mav.core.frames import FixOutcome, Tick
from taco_mav.core.smoother import FixNode, SmoothResult, smooth
from taco_mav.core.params import SmootherParams
from taco_mav.core.types import FixQuery
from taco_mav.core.ukf import PlanarUkf

__all__ = ["RunRecord"]


class RunRecord:
    """The records of one run (see the module docstring), started at pose (x, y, heading) ENU m / rad."""

    def __init__(self, x: float, y: float, heading: float) -> None:
        self.track: list[tuple[float, float, float, float, float, float, float]] = []  # t, x, y, th, Pxx, Pxy, Pyy
        self.outcomes: list[FixOutcome] = []
        self.queries: list[FixQuery] = []
        self.lock_events: list[tuple[float, str, str]] = []  # (t s, kind, detail), every one
        self._x: list[np.ndarray] = [np.array([x, y, heading])]
        self._inc: list[tuple[float, float, float]] = []
        self._sigma: list[float] = []
        self._fixes: dict[int, FixNode] = {}

    def track_state(self, t: float, ukf: PlanarUkf) -> None:
        """The filter's position, heading and position covariance at time t (s)."""
        x, P = ukf.x, ukf.P
        self.track.append((t, float(x[0]), float(x[1]), float(x[2]), float(P[0, 0]), float(P[0, 1]), float(P[1, 1])))

    def frame(self, tick: Tick, odometry_sigma: float, ukf: PlanarUkf) -> None:
        """A new frame for the smoother (its odometry sigma, m) and the track."""
        inc = tick.inc
        self._x.append(tick.x[:3].copy())
        self._inc.append((inc.d_fwd, inc.d_left, inc.d_theta))
        self._sigma.append(odometry_sigma)
        self.track_state(tick.t, ukf)

    def restate(self, ticks: Iterable[Tick]) -> None:
        """Frames whose state a rewind changed."""
        for h in ticks:
            self._x[h.node] = h.x[:3].copy()

    def fix(self, tick: Tick, xy: np.ndarray, sigma_fwd: float, sigma_lat: float) -> None:
        """A camera fix at `tick`: ENU m, body-frame 1-sigmas m."""
        self._fixes[tick.node] = FixNode(tick.node, xy.copy(), sigma_fwd, sigma_lat)

    def smoothed(self, params: SmootherParams) -> SmoothResult:
        """The Pose2 smoother over everything recorded."""
        inc = np.array(self._inc).reshape(-1, 3)
        fixes = [self._fixes[k] for k in sorted(self._fixes)]
        return smooth(np.array(self._x), inc, np.array(self._sigma), fixes, params)
