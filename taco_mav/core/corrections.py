"""The corrections a filter frame keeps: small measurement records the `Timeline` applies to the UKF at their
frame, first when they arrive and again whenever a later (late) correction rewinds to an earlier frame and
replays the frames after it. A correction is applied through the timeline and nowhere else, so every replay
applies every correction by construction.

Within a frame they are applied after the frame's predict and compass update, in the order of their `stage`
(a stop's or the wheels' speed update, the speed fed back into the preintegrator, a camera fix's position, its heading, the
real GNSS): the order the estimator's maths was written in. World frame ENU metres, headings ENU radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from taco_mav.core.ukf import PlanarUkf

if TYPE_CHECKING:
    from taco_mav.core.preintegration import Increment

__all__ = ["Correction", "Frame", "GnssCorrection", "GnssMeasurement", "GnssUpdate", "HeadingFix", "PositionFix",
           "SpeedFeedback", "WheelSpeed", "ZeroSpeed"]


class Frame(Protocol):
    """What a correction reads of the frame it is kept on (frames.Tick): the frame's increment and the speed moved
    into the preintegrator after it, m/s."""

    inc: Increment
    dv_fed: float


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




class Correction(Protocol):
    """A measurement kept on its frame. stage: its place among the frame's corrections (lower first); settles:
    whether the frame's anchor window restarts after it (the error model's drift starts again from there)."""

    stage: ClassVar[int]
    settles: ClassVar[bool]

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        """Update `ukf` (whose state is the frame's, after its predict and compass update) with this measurement;
        returns its normalised innovation squared where it has one (else 0)."""


@dataclass(frozen=True)
class ZeroSpeed:
    """A stop (taco+): the true speed is 0 at the frame end, so the speed error dv = -(the preintegrated speed
    there); sigma_mps its 1-sigma, m/s."""

    sigma_mps: float
    stage: ClassVar[int] = 0
    settles: ClassVar[bool] = False

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        ukf.update_speed_error(-tick.inc.speed_end, self.sigma_mps)
        return 0.0


@dataclass(frozen=True)
class WheelSpeed:
    """The wheels' speed (taco+, plus/wheel_speed.py): the speed error at the frame end measured as dv (m/s, the
    wheels' scaled speed less the preintegrated speed at the same time, in the frame's terms before its speed is
    fed back), 1-sigma sigma_mps. Kept beside a stop's, before the feedback."""

    dv: float
    sigma_mps: float
    stage: ClassVar[int] = 0
    settles: ClassVar[bool] = False

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        ukf.update_speed_error(self.dv, self.sigma_mps)
        return 0.0


@dataclass(frozen=True)
class SpeedFeedback:
    """taco+'s error-state feedback: the speed error moved into the preintegrator after this frame
    (`Tick.dv_fed`, m/s) is taken out of the speed-error state again when the frame is replayed."""

    stage: ClassVar[int] = 1
    settles: ClassVar[bool] = False

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        if tick.dv_fed:
            ukf.x[3] -= tick.dv_fed
        return 0.0


@dataclass(frozen=True)
class PositionFix:
    """A camera fix: position z (ENU m, shape (2,)) with covariance R (m^2, 2x2)."""

    z: np.ndarray
    R: np.ndarray
    stage: ClassVar[int] = 2
    settles: ClassVar[bool] = False

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        return ukf.update_position(self.z, self.R)


@dataclass(frozen=True)
class HeadingFix:
    """The true heading a camera fix measures (taco+): theta ENU rad, sigma 1-sigma rad."""

    theta: float
    sigma_rad: float
    stage: ClassVar[int] = 3
    settles: ClassVar[bool] = False

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        ukf.update_true_heading(self.theta, self.sigma_rad)
        return 0.0


class GnssUpdate(Protocol):
    """What a real GNSS reading does to the filter: the paper re-anchors, taco+ makes a Kalman update."""

    def apply(self, ukf: PlanarUkf, tick: Frame, m: GnssMeasurement) -> None:
        """Apply reading `m` at `tick` to `ukf`, whose state is tick's."""


@dataclass(frozen=True)
class GnssCorrection:
    """A real GNSS reading referred to this frame, applied by the estimator's `GnssUpdate`."""

    m: GnssMeasurement
    update: GnssUpdate
    stage: ClassVar[int] = 4
    settles: ClassVar[bool] = True

    def apply(self, ukf: PlanarUkf, tick: Frame) -> float:
        self.update.apply(ukf, tick, self.m)
        return 0.0
