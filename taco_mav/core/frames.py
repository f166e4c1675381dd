"""The records the Localiser keeps and hands out, frame by frame: `Tick` (one processed filter frame in the
bounded history that delayed fixes and GNSS readings rewind to), `GnssMeasurement` (a receiver reading referred
to a frame's end) and `FixOutcome` (what became of one answered query). Plain data, shared by the Localiser, its
GNSS fusion and taco+, and read by the evaluation. Positions ENU metres, headings ENU rad, times s."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from taco_mav.core.error_model import AnchorWindow, ErrorTerms, Moments
from taco_mav.core.preintegration import Increment

__all__ = ["FixOutcome", "GnssMeasurement", "Tick"]


@dataclass(frozen=True)
class GnssMeasurement:
    """One reading referred to the end of a filter frame (kept on the frame for replays).
    t: the reading's time, s; xy: position at the frame end, ENU m (2,); var_xy: its variance, m^2 (each
    axis); speed: ground speed at the frame end, m/s (the reading's less what the preintegrator gained since),
    or None; var_speed: (m/s)^2; course: grid course at the frame end, ENU rad (the reading's less the heading
    change since), or None; var_course: rad^2."""

    t: float
    xy: np.ndarray
    var_xy: float
    speed: float | None = None
    var_speed: float = 0.0
    course: float | None = None
    var_course: float = 0.0


@dataclass
class Tick:
    """One processed filter frame, kept in the bounded history for delayed fixes."""

    node: int
    t: float
    inc: Increment
    residual: Moments
    theta_start: float  # compass heading at the start of the increment, ENU rad
    x: np.ndarray = field(default_factory=lambda: np.zeros(3))
    P: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    window: AnchorWindow = AnchorWindow()
    pre_xy: tuple[float, float] = (0.0, 0.0)
    terms: ErrorTerms = ErrorTerms(0.0, 0.0, 0.0)
    fix: tuple[np.ndarray, np.ndarray] | None = None  # (z, R) applied at this frame
    fix_heading: tuple[float, float] | None = None  # taco+: (true heading ENU rad, 1-sigma rad) of that fix
    stationary: bool = False  # taco+: zero-velocity update at this frame
    dv_fed: float = 0.0  # taco+: speed error moved into the preintegrator after this frame, m/s
    track_unit: tuple[float, float] | None = None  # taco+: integral of the unit heading vector to this frame, s
    scale_track: tuple[float, float] | None = None  # taco+: displacement on the camera's speed to this frame, ENU m
    gnss: list[GnssMeasurement] = field(default_factory=list)  # real GNSS applied at this frame (replayed)


@dataclass(frozen=True)
class FixOutcome:
    """What happened to one answered query. accepted: fused; reason: "accepted", "yaw_gate", "stale",
    "unknown_query", "no_results", "nonfinite", "at_chance" (no answer beat the trigger's decoys,
    core/answer_check.py) or taco+'s "weak", "deferred", "innovation_gate", "unconfirmed"; chosen: index of the winning crop; xy: the fix, ENU metres;
    yaw_residual: rad; sigma_fwd/sigma_lat: metres; nis: normalised innovation squared; delay_s: arrival
    minus capture time; weights: w of every crop."""

    query_id: int
    accepted: bool
    reason: str
    capture_t: float
    arrival_t: float
    chosen: int = -1
    xy: np.ndarray | None = None
    yaw_residual: float = 0.0
    sigma_fwd: float = 0.0
    sigma_lat: float = 0.0
    nis: float = 0.0
    weights: tuple[float, ...] = ()
