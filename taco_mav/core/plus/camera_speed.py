"""taco+'s use of the camera's speed (not in the paper): the ground-plane motion between two frames
(`cvgl.ground_motion`, measured by the daemon's motion loop) as a measurement of the speed error, and the
receiver's ground speed checked against it (`speed_check`). A part of taco+ (estimator.py), acting on the filter
of the Localiser it serves.

Speeds m/s, distances metres, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from taco_mav.core.frames import Tick
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.timeline import Timeline
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.speed_check import SpeedCheck
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.types import GnssFix, GnssOutcome


class CameraSpeed:
    """The camera's speed for the Localiser's `timeline`: `feedback` moves the speed error into the preintegrator
    (`PlusAids.feedback`); stops (`zero`) and the safety guard (`guard`) hear what the camera saw."""

    def __init__(self, timeline: Timeline, gnss: GnssFusion, q: PlusParams, zero: ZeroVelocity, guard: SafetyGuard,
                 feedback: Callable[[Tick], None]) -> None:
        self.timeline, self.gnss, self.q, self.zero, self.guard = timeline, gnss, q, zero, guard
        self._feedback = feedback
        self.speed_check = SpeedCheck()  # GNSS ground speed against the camera's (spoofing, speed_check.py)
        self._gated = 0  # camera speed measurements held off in a row
        self._suspect, self._agree = False, 0  # camera locked onto something else

    def add(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane translation between its frames at t0 and t1 (autopilot s), in frame 0's
        body axes (metres, 1-sigma metres), as a speed measurement of the speed error x[3] at the middle of the
        interval (the speed error is taken as unchanged since). Motion vetoes zero-velocity updates for a
        second. A measurement far outside the filter's speed uncertainty is held off (chi-square, 1 dof,
        99.9 %), and three in a row, when the IMU alone sides with the camera, make a zero-velocity update
        since the last fix suspect and open the speed variance (`_camera_sides_with_imu`); when the IMU sides
        with the filter instead, the camera is suspect (locked onto a lead car or a repeating marking): its
        measurements are refused until two in a row agree with the filter within their own noise, however far
        the speed variance has grown meanwhile. Returns "used", "suspect",
        "gated", "lateral" (sideways motion: a heading change the compass got wrong), "stale" (its frames are
        older than the history) or "invalid"."""
        dt = t1 - t0
        if not (math.isfinite(dt) and math.isfinite(d_fwd) and math.isfinite(d_left) and math.isfinite(sigma_m)) \
                or dt <= 0.05 or sigma_m <= 0.0 or math.hypot(d_fwd, d_left) > 60.0 * dt:
            return "invalid"
        # A wheeled vehicle barely slips sideways: a large lateral motion is a heading change the compass got
        # wrong between the frames (an AHRS still settling), and the forward part is not to be trusted either.
        if abs(d_left) > self.q.camera_lateral_max_m + 0.3 * abs(d_fwd):
            return "lateral"
        v_cam = d_fwd / dt
        self._check_gnss_speed(0.5 * (t0 + t1), v_cam, math.sqrt(2.0) * sigma_m / dt)
        if abs(v_cam) >= self.q.zupt_speed_max_mps:
            self.zero.camera_moving(t1 + 1.0)
        v_est = self._speed_at(0.5 * (t0 + t1))
        if v_est is None:
            return "stale"
        var = 2.0 * (sigma_m / dt) ** 2 + (self.q.camera_speed_scale_sigma * v_cam) ** 2
        z = v_cam - v_est
        P33 = float(self.timeline.ukf.P[3, 3])
        if self._suspect:  # locked onto something else: used again once it agrees twice on its own noise
            if z * z > 10.83 * var and not self._camera_sides_with_imu(v_cam, v_est):
                self._agree = 0
                return "suspect"
            self._agree += 1
            if self._agree < 2:
                return "suspect"
            self._suspect = False
        if z * z > 10.83 * (P33 + var):
            self._gated += 1
            if self._gated >= 3:
                if self._camera_sides_with_imu(v_cam, v_est):
                    self.guard.distrust_zupt()
                    self.guard.speed_variance_at_least(z * z)
                else:  # the camera is the one that is wrong: hold it off until it agrees again
                    self._suspect, self._agree = True, 0
            return "gated"
        self._gated = 0
        before = self.timeline.ukf.x[:2].copy()
        self.timeline.ukf.update_speed_error(float(self.timeline.ukf.x[3]) + z, math.sqrt(var))
        if self.guard.unaided.started:  # the position moved with the speed (their correlation): not dead reckoning
            self.guard.unaided.x += float(self.timeline.ukf.x[0] - before[0])
            self.guard.unaided.y += float(self.timeline.ukf.x[1] - before[1])
        if self.timeline.history:  # a rewind to the last frame (a late fix) starts from the updated state
            self.timeline.history[-1].x, self.timeline.history[-1].P = self.timeline.ukf.get_state()
            self._feedback(self.timeline.history[-1])
        self.zero.seen(math.sqrt(max(float(self.timeline.ukf.P[3, 3]), 0.0)))
        return "used"

    def _camera_sides_with_imu(self, v_cam: float, v_est: float) -> bool:
        """Whether, when the camera and the filter keep disagreeing, the IMU alone (the unaided track since the
        last fix) is nearer the camera's speed than the filter's: then the filter lost the motion (a stop taken
        for a cruise or the reverse) and its speed variance is raised so the camera can correct it. Otherwise the
        camera is the one that is wrong (a lead car, a repeating road marking locked onto) and stays gated.
        Without an unaided track, the camera is given the benefit of the doubt."""
        if not self.guard.unaided.started:
            return True
        v_imu = float(self.guard.unaided.v)
        return abs(v_cam - v_imu) < abs(v_est - v_imu)

    def after_gnss(self, fix: GnssFix, out: GnssOutcome) -> None:
        """A GNSS reading went through the fusion: its ground speed also goes to the camera-speed check."""
        v = fix.vel_en
        if v is not None and out.reason != "nonfinite":
            self.speed_check.add_gnss(fix.t, float(math.hypot(v[0], v[1])), float(fix.sigma_v_mps))

    def _check_gnss_speed(self, t: float, v_cam: float, sigma_white: float) -> None:
        """The camera's speed against the receiver's (speed_check.py); a receiver whose speed departs from the
        camera's is flagged to the GNSS guard (rejected at its next reading, held off while it disagrees)."""
        g = self.gnss.guard
        if g is None:
            return
        trusted = g.healthy_at(t) and not g.suspect
        gap = self.speed_check.add_camera(t, v_cam, sigma_white, trusted)
        if gap is not None:
            g.external_flag = f"camera_speed {gap:+.2f} m/s"

    def _speed_at(self, t: float) -> float | None:
        """The estimate's forward speed (m/s) at autopilot time t, interpolated between history frames; None
        before the history."""
        h = self.timeline.history
        if not h or t < h[0].t - self.timeline.frame_dt:
            return None
        speeds = [(k.t, k.inc.speed_end + k.dv_fed) for k in h]
        if t >= speeds[-1][0]:
            return float(self.timeline.pre.speed)
        for (ta, va), (tb, vb) in zip(speeds, speeds[1:]):
            if ta <= t <= tb:
                return va + (vb - va) * (t - ta) / max(tb - ta, 1e-9)
        return speeds[0][1]
