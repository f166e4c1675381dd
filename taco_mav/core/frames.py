"""The records the Localiser keeps and hands out, frame by frame: `Tick` (one processed filter frame in the
bounded history that delayed fixes and GNSS readings rewind to), `GnssMeasurement` (a receiver reading referred
to a frame's end) and `FixOutcome` (what became of one answered query). Plain data, shared by the Localiser, its
GNSS fusion and taco+, and read by the evaluation. Positions ENU metres, headings ENU rad, times s."""

from __future__ import annotations

import enum
from dataclasses import KW_ONLY, dataclass, field

import numpy as np

from taco_mav.core.corrections import Correction, GnssCorrection, GnssMeasurement
from taco_mav.core.error_model import AnchorWindow, ErrorTerms, Moments
from taco_mav.core.preintegration import Increment

__all__ = ["FixOutcome", "FixReason", "GnssMeasurement", "Tick"]


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
    corrections: list[Correction] = field(default_factory=list)  # applied at this frame (replayed), by stage
    dv_fed: float = 0.0  # speed moved into the preintegrator after this frame, m/s
    track_unit: tuple[float, float] | None = None  # taco+: integral of the unit heading vector to this frame, s
    scale_track: tuple[float, float] | None = None  # taco+: displacement on the camera's speed to this frame, ENU m
    wheel_track: tuple[float, float] | None = None  # taco+: displacement on the wheels' raw speed to here, ENU m

    def add(self, c: Correction) -> None:
        """Keep correction `c` on this frame, in stage order (after those of its stage already kept)."""
        i = len(self.corrections)
        while i > 0 and self.corrections[i - 1].stage > c.stage:
            i -= 1
        self.corrections.insert(i, c)

    @property
    def gnss(self) -> list[GnssMeasurement]:
        """The real GNSS readings applied at this frame."""
        return [c.m for c in self.corrections if isinstance(c, GnssCorrection)]

    def drop_gnss(self) -> None:
        """Forget the real GNSS readings applied at this frame (a rollback replays without them)."""
        self.corrections = [c for c in self.corrections if not isinstance(c, GnssCorrection)]


class FixReason(enum.StrEnum):
    """What became of an answered query (`FixOutcome.reason`)."""

    ACCEPTED = "accepted"  # fused
    UNKNOWN_QUERY = "unknown_query"  # it answers no query in flight
    NO_RESULTS = "no_results"  # no crop could be matched
    NONFINITE = "nonfinite"  # no finite answer with a positive weight
    YAW_GATE = "yaw_gate"  # the answer's rotation disagrees with the compass (paper Sec. III-E)
    AT_CHANCE = "at_chance"  # no answer beat the trigger's chance level or the crops disagree (answer_check.py)
    STALE = "stale"  # its capture frame left the history
    WEAK = "weak"  # taco+: no answer strong enough for a consensus
    DEFERRED = "deferred"  # taco+: weak, and the filter can wait for a better one
    INNOVATION_GATE = "innovation_gate"  # taco+: too far from the track for its covariance
    UNCONFIRMED = "unconfirmed"  # taco+: a jump held until a second answer confirms it
    REFUTED = "refuted"  # taco+: the GNSS readings refute the camera (gnss/guard.py `camera_refuted`)


@dataclass(frozen=True)
class FixOutcome:
    """What happened to one answered query. accepted: fused; reason: why (`FixReason`); capture_t, arrival_t:
    the query's capture and the answer's arrival, autopilot s; chosen: index of the winning crop; xy: the fix,
    ENU metres; yaw_residual: rad; sigma_fwd/sigma_lat: metres; nis: normalised innovation squared; weights: w
    of every crop."""

    query_id: int
    accepted: bool
    reason: FixReason
    capture_t: float
    arrival_t: float
    _: KW_ONLY
    chosen: int = -1
    xy: np.ndarray | None = None
    yaw_residual: float = 0.0
    sigma_fwd: float = 0.0
    sigma_lat: float = 0.0
    nis: float = 0.0
    weights: tuple[float, ...] = ()
