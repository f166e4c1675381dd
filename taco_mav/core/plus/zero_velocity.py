"""taco+'s zero-velocity updates (not in the paper): when a frame is taken as a stop, and the update it makes.

The IMU alone cannot tell a smooth cruise from a stop (`stationary.StationaryDetector` only says "IMU still"), so
a frame is a stop only when the IMU is still and the speed is one the filter cannot tell from zero. The speed the
IMU may have lost since the speed was last observed (a fix, a stop, a camera speed) is what its accelerometer
error integrates to, not the filter's speed random walk (with q_speed 0.5 a smooth 3 m/s cruise falls inside
3 sigma within seconds and the update would pin it to zero). Never while the autopilot drives or the camera
sees the ground move, nor while the safety guard holds updates off. A part of taco+ (estimator.py).

Speeds m/s, times autopilot seconds.
"""

from __future__ import annotations

import math

from taco_mav.core.frames import Tick
from taco_mav.core.timeline import Timeline
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.stationary import StationaryDetector
from taco_mav.core.types import ImuSample


class ZeroVelocity:
    """Stops for the Localiser's `timeline`: the stationary detector, the last speed observation, the autopilot's drive
    command and the camera's motion veto; the safety guard's hold-off (`guard`)."""

    def __init__(self, timeline: Timeline, q: PlusParams, guard: SafetyGuard, t0: float) -> None:
        self.timeline, self.q, self.guard = timeline, q, guard
        self.still = StationaryDetector(q.zupt_window_s, q.zupt_gyro_max_rps, q.zupt_accel_std_max_mps2,
                                        q.zupt_accel_mean_max_mps2)
        self.active = False  # the last frame had a zero-velocity update
        self._seen_t, self._seen_sigma = t0, q.initial_speed_sigma_mps  # last speed observation (s, m/s)
        self._drive: tuple[float, bool] | None = None  # (t, the autopilot drives) from set_drive_command
        self._camera_moving_until = -math.inf  # the camera saw the ground move: no zero-velocity update

    def add_imu(self, sample: ImuSample, accel_fwd: float) -> None:
        """One fresh IMU sample for the detector (accel_fwd: gravity-compensated forward, m/s^2)."""
        self.still.add(sample.t, sample.accel_frd, sample.gyro_frd, accel_fwd)

    def set_drive_command(self, t: float, driving: bool) -> None:
        """What the autopilot commands at time t (s): True while it drives (armed with a throttle output), False
        while it does not. A driving autopilot vetoes zero-velocity updates (for drive_command_timeout_s)."""
        self._drive = (t, driving)

    def camera_moving(self, until: float) -> None:
        """The camera saw the ground move: no zero-velocity update until `until` (s)."""
        self._camera_moving_until = max(self._camera_moving_until, until)

    def seen(self, sigma_mps: float) -> None:
        """The speed was just observed (a stop, a fix) with this 1-sigma, m/s."""
        self._seen_t, self._seen_sigma = self.timeline.t, sigma_mps

    def stopped_on_command(self) -> bool:
        """The autopilot recently said it does not drive (within drive_command_timeout_s)."""
        d = self._drive
        return d is not None and not d[1] and self.timeline.t - d[0] <= self.q.drive_command_timeout_s

    def _driving(self) -> bool:
        """The autopilot drives (a recent drive command), or the camera saw the ground move."""
        d, t = self._drive, self.timeline.t
        return (d is not None and d[1] and t - d[0] <= self.q.drive_command_timeout_s
                or t <= self._camera_moving_until)

    def decide(self) -> bool:
        """Whether the new frame is a stop (see the module docstring): then true speed 0 at its end."""
        tl, q = self.timeline, self.q
        tau = max(tl.t - self._seen_t, 0.0)
        drift = (math.sqrt(max(float(tl.ukf.P[4, 4]), 0.0)) + q.imu_accel_sigma_mps2) * tau
        gate = q.zupt_speed_max_mps + 3.0 * (self._seen_sigma + drift)
        bias = float(tl.ukf.x[4])
        stop = bool(q.zupt and abs(tl.pre.speed) <= gate and tl.t >= self.guard.zupt_holdoff_until
                    and not self._driving() and self.still.still(bias))
        if stop:
            self.seen(q.zupt_sigma_mps)
            self.guard.zupt_since_reset = True
        self.active = stop
        return stop
