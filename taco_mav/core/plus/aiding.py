"""taco+'s aiding of the filter beyond the paper (the `Aids` of estimator.py): stops (zero_velocity.py), the
camera's speed (camera_speed.py) and its scale error (speed_scale.py), the wheels' speed (wheel_speed.py, when the
profile has wheels), the autopilot's drive command, the IMU-only safety guard (safety_guard.py), the lock's events, and the error-state feedback that moves the speed-error
estimate into the preintegrator after every frame (kept on the frame as a `SpeedFeedback` correction, so a
replay takes it out of the state again).

World frame ENU metres, speeds m/s, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

import math

from taco_mav.core.corrections import SpeedFeedback, ZeroSpeed
from taco_mav.core.frames import FixOutcome, FixReason, Tick
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.answer_hold import AnswerHold
from taco_mav.core.plus.camera_speed import CameraSpeed
from taco_mav.core.plus.lock import LockMonitor
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.progress import Progress
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.speed_scale import ScaleConsider
from taco_mav.core.plus.wheel_speed import WheelAiding
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import GnssFix, GnssOutcome, ImuSample
from taco_mav.core.wheel_odometry import WheelMotion

__all__ = ["PlusAids"]


class PlusAids:
    """taco+'s aiding on the Localiser's `timeline` (see the module docstring); the camera's speed is checked
    against the receiver's in `gnss`."""

    def __init__(self, timeline: Timeline, gnss: GnssFusion, params: LocaliserParams, q: PlusParams, *,
                 lock: LockMonitor, progress: Progress, guard: SafetyGuard, zero: ZeroVelocity,
                 scale: ScaleConsider, answers: AnswerHold) -> None:
        self.timeline, self.p, self.q = timeline, params, q
        self.lock, self.progress, self.guard, self.zero, self.scale, self.answers = (
            lock, progress, guard, zero, scale, answers)
        self.camera = CameraSpeed(timeline, gnss, q, zero, guard, self.feedback)
        self.wheels = WheelAiding(timeline, params.wheels, zero) if params.wheels is not None else None
        self.lock_events = lock.events
        self._track_unit = (0.0, 0.0)  # integral of the compass's unit heading vector over time, s (ENU)

    # ------------------------------------------------------------------ IMU path and frames
    def before_imu(self) -> None:
        if self.q.guard and not self.guard.unaided.started:
            self.guard.reset()

    def after_imu(self, sample: ImuSample) -> None:
        pre = self.timeline.pre
        self.zero.add_imu(sample, pre.accel_fwd)
        if self.q.guard:
            self.guard.add_imu(sample.t, pre.accel_fwd, pre.theta)
        if self.wheels is not None:
            self.wheels.after_imu(sample, pre.speed)

    def set_drive_command(self, t: float, driving: bool) -> None:
        self.zero.set_drive_command(t, driving)

    def open_frame(self, tick: Tick) -> None:
        inc = tick.inc  # what a speed error of 1 m/s moves the estimate by over this frame, ENU metres
        mid = tick.theta_start + 0.5 * inc.d_theta
        ux, uy = self._track_unit
        self._track_unit = tick.track_unit = (ux + inc.dt * math.cos(mid), uy + inc.dt * math.sin(mid))
        self.scale.advance(tick, mid)
        if self.zero.decide():
            tick.add(ZeroSpeed(self.q.zupt_sigma_mps))
        if self.wheels is not None:
            wheel = self.wheels.open_frame(tick, mid)
            if wheel is not None:
                tick.add(wheel)

    def close_frame(self, tick: Tick) -> None:
        self.progress.odo += tick.inc.distance
        self.feedback(tick)
        if self.q.gyro_heading:  # the gyro integrates on from the filter's heading
            self.timeline.pre.rebase_heading(float(self.timeline.ukf.x[2]))
        if self.q.guard:
            self.guard.check()

    def feedback(self, tick: Tick) -> None:
        """Move the speed-error estimate into the preintegrator (clamped at 0 unless reversing is allowed), kept on
        frame `tick` for replays."""
        pre, ukf = self.timeline.pre, self.timeline.ukf
        old = pre.speed
        new = old + float(ukf.x[3])
        if not self.p.imu.allow_reverse:
            new = max(new, 0.0)
        applied = new - old
        if applied:
            pre.speed = new
            ukf.x[3] -= applied
            if self.wheels is not None:
                self.wheels.fed_back(applied)
            if not any(isinstance(c, SpeedFeedback) for c in tick.corrections):
                tick.add(SpeedFeedback())
            tick.dv_fed += applied
            tick.x[3] -= applied

    # ------------------------------------------------------------------ other inputs and events
    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane motion as a speed measurement (camera_speed.py)."""
        used = self.camera.add(t0, t1, d_fwd, d_left, sigma_m)
        if used == "used":
            self.scale.camera_used(t1)
        return used

    def add_wheel_speed(self, m: WheelMotion) -> str:
        """The wheels' speed between two WHEEL_DISTANCE samples (wheel_speed.py): "used", or why not; "off" when
        the profile has no wheels."""
        return "off" if self.wheels is None else self.wheels.add(m)

    def wheels_refused(self) -> str | None:
        """Why the wheel source is refused now ("slip", "stuck", "disagrees"), None while it is in use or absent."""
        return None if self.wheels is None else self.wheels.refused

    def answer_missing(self, out: FixOutcome) -> None:
        """An answer that answers no query in flight, or holds nothing (`out`): the latter counts towards loss of
        lock."""
        self.progress.last_answer_t = self.timeline.t
        if out.reason is FixReason.NO_RESULTS:
            self.answers.failed(out.reason, 0.0, self.progress.odo)

    def after_gnss(self, fix: GnssFix, out: GnssOutcome) -> None:
        self.camera.after_gnss(fix, out)
        if out.used:
            self.scale.pin()

    def after_gnss_rollback(self) -> None:
        """The replay left the undone speed corrections in the speed error: feed it back."""
        if self.timeline.history:
            self.feedback(self.timeline.history[-1])
        if self.q.guard:
            self.guard.reset()

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """The lock events not yet taken (the daemon logs each once)."""
        return self.lock.take_unreported()
