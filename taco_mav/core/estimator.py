"""The estimator a Localiser composes (localiser.py): what differs between the paper's method (paper.py,
`make_paper`) and taco+ (plus/estimator.py, `make_plus`), as parts chosen from the parameters. The Localiser's
timeline runs what both share (the IMU path, the frames, every correction's rewind and replay), its query desk the
query in flight, its GNSS fusion the receiver. The parts give the filter (its states, prior and predict), the
trigger, what an answer does, what a GNSS reading does, the reported accuracy (taco+) and taco+'s aiding, which
the paper has none of.

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from taco_mav.core.corrections import GnssUpdate
from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.frames import FixOutcome, GnssMeasurement, Tick
from taco_mav.core.queries import Answering
from taco_mav.core.types import Estimate, GnssFix, GnssOutcome, ImuSample, MatchResult
from taco_mav.core.ukf import PlanarUkf
from taco_mav.core.wheel_odometry import WheelMotion

__all__ = ["Aids", "EstimatorParts", "FilterModel", "FixPolicy", "GnssPolicy", "Plan", "Report", "Trigger"]

Plan = tuple[str, float, np.ndarray]  # a trigger's (reason, forward bias m, body offsets (K, 2) m)


class FilterModel(Protocol):
    """The filter: its states and prior, its predict over one frame and the smoother's odometry noise."""

    def make_ukf(self, x: float, y: float, heading: float) -> PlanarUkf:
        """The filter at the start pose (ENU m, ENU rad)."""

    def predict(self, ukf: PlanarUkf, tick: Tick, terms: ErrorTerms) -> None:
        """The UKF predict over one frame (new or replayed), given the error model's terms."""

    def odometry_sigma(self, tick: Tick) -> float:
        """The smoother's isotropic odometry sigma for this frame, metres."""


class Trigger(Protocol):
    """When to ask the matcher, and where."""

    def plan(self) -> Plan | None:
        """The query due now, or None."""


class FixPolicy(Protocol):
    """What an answer does."""

    def judge(self, answer: Answering, results: Sequence[MatchResult | None]) -> FixOutcome:
        """The matcher's answer to the query in flight: fused through the timeline, or refused with a reason."""


class GnssPolicy(GnssUpdate, Protocol):
    """What a real GNSS reading does (as a `GnssUpdate`, its update at a frame) and what the guard reads of it."""

    replaces: bool  # a reading replaces the position (paper) rather than updating it (taco+)

    def fused(self, tick: Tick, m: GnssMeasurement) -> None:
        """After a batch of readings was fused and replayed; `m` the newest, referred to `tick`."""

    def anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        """(true-speed estimate m/s, accelerometer bias m/s^2, compass bias rad, their 1-sigmas with the
        heading's) at tick's end, for the GNSS guard's shadow anchor."""


class Report(Protocol):
    """The reported accuracy, calibrated beyond the filter's own covariance."""

    def report(self, est: Estimate) -> Estimate:
        """The reported estimate from the filter's own."""


class Aids(Protocol):
    """Aiding beyond the paper: stops, the camera's speed, the autopilot's drive command, the IMU-only safety guard
    and the lock state machine."""

    lock_events: list[tuple[float, str, str]]  # every lock event so far, (t s, kind, detail)

    def before_imu(self) -> None:
        """Before a fresh IMU sample is integrated."""

    def after_imu(self, sample: ImuSample) -> None:
        """After a fresh IMU sample was integrated (and its frame, if one closed, advanced)."""

    def open_frame(self, tick: Tick) -> None:
        """Before a new frame is advanced (what it keeps for replays, whether it is a stop)."""

    def close_frame(self, tick: Tick) -> None:
        """After a new frame joined the history."""

    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane motion as a speed measurement."""

    def set_drive_command(self, t: float, driving: bool) -> None:
        """Whether the autopilot drives at time t."""

    def add_wheel_speed(self, m: WheelMotion) -> str:
        """The wheels' speed as a speed measurement ("used", or why not; "off" without wheels)."""

    def wheels_refused(self) -> str | None:
        """Why the wheel source is refused now, None while it is in use or absent."""

    def answer_missing(self, out: FixOutcome) -> None:
        """An answer that answers no query in flight or holds nothing (`out`)."""

    def after_gnss(self, fix: GnssFix, out: GnssOutcome) -> None:
        """After a GNSS reading went through the fusion (its ground speed to the camera-speed check)."""

    def after_gnss_rollback(self) -> None:
        """After the readings fused since the guard's reference were undone."""

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """The lock events not yet taken."""


@dataclass(frozen=True)
class EstimatorParts:
    """An estimator mode's parts (see the module docstring); report and aids None where the mode has none."""

    filter: FilterModel
    trigger: Trigger
    fixes: FixPolicy
    gnss: GnssPolicy
    report: Report | None
    aids: Aids | None
