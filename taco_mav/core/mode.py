"""The estimator mode behind the Localiser: what differs between the paper's method (`paper.PaperMode`) and taco+
(`plus.mode.PlusMode`). The Localiser (localiser.py) runs what both share, the IMU path, the frames, the history
that a late answer rewinds to and replays, the query in flight and the real-GNSS fusion, and asks its mode at
each of these hooks.

A mode is made by the Localiser it serves (the `host`) and reads and adjusts the host's filter (`host.ukf`,
`host.pre`, `host.history`, `host.t`) through the host's public attributes and methods. World frame ENU metres,
headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np

from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.frames import FixOutcome, GnssMeasurement, Tick
from taco_mav.core.types import Estimate, GnssFix, GnssOutcome, ImuSample, MatchResult
from taco_mav.core.ukf import PlanarUkf

__all__ = ["Mode"]


class Mode(Protocol):
    """The hooks a Localiser calls on its mode (see the module docstring)."""

    takes_ground_motion: bool  # add_ground_motion is used (a speed measurement)
    gnss_replaces: bool  # a GNSS reading replaces the position (paper) rather than updating it (taco+)

    def make_ukf(self, x: float, y: float, heading: float) -> PlanarUkf:
        """The filter at the start pose (ENU m, ENU rad) with the mode's states and prior."""

    # the IMU path and the frames
    def before_imu(self, fresh: bool) -> None:
        """Before an IMU sample is integrated (fresh: newer than the last)."""

    def after_imu(self, sample: ImuSample) -> None:
        """After a fresh IMU sample was integrated (and its frame, if one closed, advanced)."""

    def open_tick(self, tick: Tick) -> None:
        """Before a new frame is advanced."""

    def predict(self, tick: Tick, terms: ErrorTerms) -> None:
        """The UKF predict over one frame (new or replayed), given the error model's terms."""

    def after_heading(self, tick: Tick) -> None:
        """Measurement updates after the compass update of a frame (new or replayed)."""

    def close_tick(self, tick: Tick) -> None:
        """After a new frame joined the history."""

    def odometry_sigma(self, tick: Tick) -> float:
        """The smoother's isotropic odometry sigma for this frame, metres."""

    # the trigger and the answers
    def plan_search(self) -> tuple[str, float, np.ndarray] | None:
        """(reason, forward bias m, body offsets (K, 2) m) of the query due now, or None."""

    def add_fix(self, query_id: int, results: Sequence[MatchResult | None]) -> FixOutcome:
        """What the matcher's answer to the query in flight does (`Localiser.add_fix`)."""

    def estimate(self, est: Estimate) -> Estimate:
        """The reported estimate from the filter's own (`Localiser.filter_estimate`)."""

    # other inputs and events
    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane motion as a speed measurement; "ignored" where the mode has none."""

    def set_drive_command(self, t: float, driving: bool) -> None:
        """Whether the autopilot drives at time t."""

    def after_gnss(self, fix: GnssFix, out: GnssOutcome) -> None:
        """After a GNSS reading went through the fusion (taco+: its ground speed to the camera-speed check)."""

    def lock_events(self) -> list[tuple[float, str, str]]:
        """Every lock event so far, (t, kind, detail)."""

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """The lock events not yet taken."""

    # what a real GNSS reading does (gnss/fusion.py calls these)
    def gnss_apply(self, tick: Tick, m: GnssMeasurement) -> None:
        """Apply a reading at `tick` to the filter's current state (which is tick's)."""

    def gnss_fused_live(self, tick: Tick, m: GnssMeasurement) -> None:
        """After a batch of readings was fused and replayed; `m` the newest, referred to `tick`."""

    def gnss_anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        """(true-speed estimate m/s, accelerometer bias m/s^2, compass bias rad, their 1-sigmas with the
        heading's) at tick's end, for the GNSS guard's shadow anchor."""

    def gnss_after_rollback(self) -> None:
        """After the readings fused since the guard's reference were undone (rewind and replay without them)."""
