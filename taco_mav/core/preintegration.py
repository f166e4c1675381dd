"""IMU preintegration (paper Sec. III-B): body-frame motion between filter frames from autopilot IMU samples.

Input per sample: body FRD specific force (m/s^2, gravity included) and attitude (roll, pitch, yaw NED, rad).
The specific force is rotated into the level (yaw-only) frame with roll and pitch; its forward component is
the gravity-compensated forward acceleration (gravity is vertical, so it has no level-forward component).
Speed integrates that acceleration; heading comes from the compass (attitude yaw, theta = pi/2 - psi in ENU).

Between two filter frames the preintegrator accumulates the planar increment (forward, left) metres in the
body frame at the start of the interval and the heading change dtheta (CCW rad): exact for arcs because each
sample's displacement is rotated by the heading change since the interval start.

It also keeps a dead-reckoned position (ENU metres, the "corrected preintegrator" of Sec. III-B) that is
reset to the UKF position on an accepted fix (position only; heading and speed preserved, Sec. III-F).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from math import atan2, cos, sin

from taco_mav.core.params import ImuParams
from taco_mav.core.types import ImuSample


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi], radians."""
    return math.atan2(math.sin(a), math.cos(a))


def enu_heading(yaw_ned: float) -> float:
    """ENU heading theta (0 = east, CCW) from a NED yaw psi (0 = north, CW): theta = pi/2 - psi."""
    return wrap_angle(math.pi / 2.0 - yaw_ned)


def level_forward_accel(accel_frd: tuple[float, float, float], roll: float, pitch: float) -> float:
    """Forward acceleration in the level frame, m/s^2, from FRD specific force and NED roll/pitch (rad).

    f_level = Ry(pitch) Rx(roll) f_body; its x component is the along-heading acceleration (gravity lies on
    the level frame's z axis and drops out).
    """
    fx, fy, fz = accel_frd
    sp, cp = math.sin(pitch), math.cos(pitch)
    sr, cr = math.sin(roll), math.cos(roll)
    return cp * fx + sp * sr * fy + sp * cr * fz


@dataclass(frozen=True, slots=True)
class Increment:
    """Body-frame motion over one filter frame. d_fwd, d_left: metres in the body frame at the frame start;
    d_theta: heading change, rad CCW; dt: seconds; distance: path length, metres; t_end: end time, s;
    theta_end: compass heading at the end, ENU rad; speed_end: m/s."""

    d_fwd: float
    d_left: float
    d_theta: float
    dt: float
    distance: float
    t_end: float
    theta_end: float
    speed_end: float

    @property
    def chord(self) -> float:
        """Straight-line length of the increment, metres."""
        return math.hypot(self.d_fwd, self.d_left)


class Preintegrator:
    """Integrates IMU samples into speed, heading and per-frame body increments.

    speed: forward speed, m/s (clamped at 0 unless allow_reverse). theta: compass heading, ENU rad.
    x, y: dead-reckoned position, ENU metres. accel_fwd: last gravity-compensated forward accel, m/s^2.
    heading_offset: added to the compass heading, rad: the UTM meridian convergence (grid heading = true
    heading + convergence), so that headings live on the same grid as the UTM positions.
    gyro_heading (taco+, plus.gyro_heading): theta integrates the gyro's yaw rate (body rates levelled by roll and
    pitch) instead of taking each sample's compass heading; `compass` keeps the compass heading, which the filter
    fuses as a slow reference (`Increment.theta_end`). `rebase_heading` sets theta to the filter's at a frame.
    tilt_lowpass_s: with a positive time constant, s, gravity is taken off the forward acceleration with the
    attitude's roll and pitch low-passed (first order) rather than each sample's (`ImuParams.tilt_lowpass_s` says
    why); 0 takes each sample's, as the paper does. `tilt`: the low-passed (roll, pitch), rad. The gyro's yaw rate
    is levelled by each sample's attitude either way.
    """

    def __init__(self, t0: float, x: float = 0.0, y: float = 0.0, theta: float = 0.0, speed: float = 0.0,
                 *, allow_reverse: bool = False, max_dt_s: float = 0.5, heading_offset: float = 0.0,
                 tilt_lowpass_s: float = 0.0) -> None:
        self.t = t0
        self.heading_offset = heading_offset
        self.x, self.y = x, y
        self.theta = theta
        self.speed = speed
        self.allow_reverse = allow_reverse
        self.max_dt_s = max_dt_s
        self.accel_fwd = 0.0
        self.gyro_heading = False
        self.compass = theta  # the last sample's compass heading, ENU rad (+ heading_offset)
        self.tilt_lowpass_s = tilt_lowpass_s
        self.tilt: tuple[float, float] | None = None
        self._reset_interval(theta)

    @classmethod
    def from_params(cls, imu: ImuParams, t0: float, x: float, y: float, theta: float, speed: float,
                    heading_offset: float = 0.0) -> "Preintegrator":
        """A preintegrator with the profile's IMU settings (reverse, longest step, tilt low-pass); the other
        arguments as the constructor's."""
        return cls(t0, x, y, theta, speed, allow_reverse=imu.allow_reverse, max_dt_s=imu.max_dt_s,
                   heading_offset=heading_offset, tilt_lowpass_s=imu.tilt_lowpass_s)

    def _reset_interval(self, theta: float) -> None:
        self._theta0 = theta
        self._c0, self._s0 = math.cos(theta), math.sin(theta)
        self._dx = self._dy = 0.0
        self._dist = 0.0
        self._dt = 0.0

    def add(self, sample: ImuSample) -> float:
        """Integrate one sample; returns the step dt actually integrated, s (0 for stale or repeated time).

        The hot path (100 Hz): `level_forward_accel`, `enu_heading` and `wrap_angle` written out inline, with
        exactly their operations in their order, so the numbers are the same to the last bit."""
        t = sample.t
        dt = t - self.t
        if dt <= 0.0:
            return 0.0
        self.t = t
        if dt > self.max_dt_s:
            dt = self.max_dt_s
        fx, fy, fz = sample.accel_frd
        pitch, roll = sample.pitch, sample.roll
        if self.tilt_lowpass_s > 0.0:
            r0, p0 = self.tilt if self.tilt is not None else (roll, pitch)
            k = min(dt / self.tilt_lowpass_s, 1.0)
            roll, pitch = r0 + k * (roll - r0), p0 + k * (pitch - p0)
            self.tilt = (roll, pitch)
        sp, cp = sin(pitch), cos(pitch)
        sr, cr = sin(roll), cos(roll)
        a = cp * fx + sp * sr * fy + sp * cr * fz  # level_forward_accel
        h = math.pi / 2.0 - sample.yaw
        h = atan2(sin(h), cos(h)) + self.heading_offset  # enu_heading + offset
        theta = atan2(sin(h), cos(h))
        self.compass = theta
        if self.gyro_heading:  # ENU heading rate = -(NED yaw rate) = -(q sin(roll) + r cos(roll)) / cos(pitch)
            _, gq, gr = sample.gyro_frd
            if self.tilt is not None:  # levelled by this sample's attitude: the low-pass is for gravity only
                sr, cr, cp = sin(sample.roll), cos(sample.roll), cos(sample.pitch)
            h = self.theta - (gq * sr + gr * cr) / cp * dt
            theta = atan2(sin(h), cos(h))
        v0 = self.speed
        v1 = v0 + a * dt
        if v1 < 0.0 and not self.allow_reverse:
            v1 = 0.0
        step = 0.5 * (v0 + v1) * dt  # trapezoid on speed
        # Displacement along the mean heading of the step (handles the wrap at +-pi).
        th0 = self.theta
        d = theta - th0
        mid = th0 + 0.5 * atan2(sin(d), cos(d))
        ex, ey = step * cos(mid), step * sin(mid)
        self.x += ex
        self.y += ey
        self._dx += ex
        self._dy += ey
        self._dist += abs(step)
        self._dt += dt
        self.speed = v1
        self.theta = theta
        self.accel_fwd = a
        return dt

    @property
    def interval_heading(self) -> float:
        """Compass heading at the start of the open frame interval, ENU rad (the increment's body frame)."""
        return self._theta0

    @property
    def interval_displacement(self) -> tuple[float, float]:
        """Displacement integrated since the start of the open frame interval, ENU metres."""
        return self._dx, self._dy

    def take_increment(self) -> Increment:
        """Close the current frame interval: the increment since the last call, in the start-of-interval body
        frame; starts a new interval."""
        c, s = self._c0, self._s0
        inc = Increment(
            d_fwd=c * self._dx + s * self._dy,
            d_left=-s * self._dx + c * self._dy,
            d_theta=wrap_angle(self.theta - self._theta0),
            dt=self._dt,
            distance=self._dist,
            t_end=self.t,
            theta_end=self.compass,
            speed_end=self.speed,
        )
        self._reset_interval(self.theta)
        return inc

    def rebase_heading(self, theta: float) -> None:
        """gyro_heading: set theta (ENU rad) to the filter's heading at a frame boundary (the open interval must
        be empty, i.e. right after `take_increment`), so the gyro integrates from the best heading known."""
        self.theta = theta
        self._reset_interval(theta)

    def reset_position(self, x: float, y: float) -> None:
        """Position-only anchor reset on an accepted fix (Sec. III-F): heading and speed are preserved."""
        self.x, self.y = x, y
