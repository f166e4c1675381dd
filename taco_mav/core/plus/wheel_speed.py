"""taco+'s use of the wheel encoders (core/wheel_odometry.py's speeds): each wheel speed checked against the filter
and the gyro, then kept until the frame its middle falls in, where it becomes a `WheelSpeed` correction (applied
through the timeline, so a late fix's replay applies it again) measuring the speed error at the frame's end. Its
scale (a wheel radius a few per cent off) is learnt from the camera's fixes (wheel_scale.py).

What is refused, and why:
- "stale": its middle is older than the IMU kept here, or than wheels.max_age_s at its frame;
- "slip": the wheels' yaw rate departs from the gyro's by more than wheels.yaw_rate_gate_rps (a wheel in the air
  spins freely; a skid turns the vehicle without its wheels), or the wheels run faster than the filter's speed;
- "stuck": the wheels read standing while the filter (IMU, camera, fixes) has the vehicle moving;
- "disagrees": the wheels are slower than the filter's speed beyond the gate otherwise;
the last three by a chi-square gate (wheels.gate_chi2) on the filter's speed variance plus the wheel's and its
scale's. wheels.refuse_after of them in a row refuse the source itself (`refused` names why) until
wheels.agree_to_resume in a row agree with the filter's speed within the wheels' own noise, however far the speed
variance grew meanwhile. Standing wheels at a frame taken for a stop (a zero-velocity
update) are never refused; a smooth cruise looks still to the IMU, so its stillness alone does not decide.

Speeds m/s, headings ENU rad, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections import deque

from taco_mav.core.corrections import WheelSpeed
from taco_mav.core.frames import Tick
from taco_mav.core.plus.wheel_scale import WheelScale
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import ImuSample
from taco_mav.core.wheel_odometry import WheelMotion
from taco_mav.core.wheel_params import WheelParams

__all__ = ["WheelAiding"]

STANDING_MPS = 0.05  # a wheel speed below this reads as standing, m/s
IN_USE_S = 1.0  # the wheel speed steers the speed this long after the last frame it was fused at, s


class WheelAiding:
    """The wheels for the Localiser's `timeline` (see the module docstring); `zero` hears that the wheels turn (no
    zero-velocity update then) and says whether the last frame was a stop."""

    def __init__(self, timeline: Timeline, w: WheelParams, zero: ZeroVelocity) -> None:
        self.timeline, self.w, self.zero = timeline, w, zero
        self.scale = WheelScale(w.scale_sigma, w.scale_walk_per_sqrt_km, w.scale_min_span_m)
        # after every IMU sample: (t s, gyro yaw rate ENU rad/s, preintegrated speed m/s less the speed fed back)
        self._imu: deque[tuple[float, float, float]] = deque(maxlen=512)
        self._fed = 0.0  # speed moved into the preintegrator so far, m/s: the kept speeds' offset to now's terms
        self._queue: list[tuple[float, float]] = []  # accepted (t_mid s, raw wheel speed m/s), awaiting their frame
        self._bad = 0  # gate failures in a row
        self._good = 0  # passes in a row while the source is refused
        self.refused: str | None = None  # why the source is refused now (None: in use)
        self.used_t = -math.inf  # end of the last frame a wheel speed was fused at, s

    # ------------------------------------------------------------------ the IMU's side
    def after_imu(self, sample: ImuSample, speed: float) -> None:
        """A fresh IMU sample integrated (its gyro's yaw rate, levelled by its attitude) and the preintegrated
        speed after it, m/s."""
        _, gq, gr = sample.gyro_frd
        sr, cr, cp = math.sin(sample.roll), math.cos(sample.roll), math.cos(sample.pitch)
        self._imu.append((sample.t, -(gq * sr + gr * cr) / cp, speed - self._fed))

    def fed_back(self, applied: float) -> None:
        """`applied` m/s of speed error was moved into the preintegrator (PlusAids.feedback)."""
        self._fed += applied

    def _speed_at(self, t: float) -> float | None:
        """The preintegrated speed (m/s, in now's terms) at autopilot time t, linear between the kept samples;
        None outside them."""
        h = self._imu
        if not h or t < h[0][0] or t > h[-1][0] + 0.05:
            return None
        prev = h[0]
        for cur in h:
            if cur[0] >= t:
                ta, tb = prev[0], cur[0]
                f = 0.0 if tb <= ta else (t - ta) / (tb - ta)
                return prev[2] + f * (cur[2] - prev[2]) + self._fed
            prev = cur
        return h[-1][2] + self._fed

    def _yaw_rate(self, t0: float, t1: float) -> float | None:
        """The gyro's mean yaw rate (ENU rad/s) over the samples from t0 to t1 (s); None without one."""
        rates = [w for t, w, _ in self._imu if t0 <= t <= t1]
        return sum(rates) / len(rates) if rates else None

    # ------------------------------------------------------------------ the wheels
    def add(self, m: WheelMotion) -> str:
        """One wheel speed: "used" (kept for its frame), "refused" (it passed, but the source is refused until
        enough in a row do), or why it was not (module docstring)."""
        v_pre = self._speed_at(m.t_mid)
        if v_pre is None or self._speed_at(m.t0) is None:
            return "stale"
        v = self.scale.s * m.speed
        if abs(m.speed) >= self.zero.q.zupt_speed_max_mps:
            self.zero.camera_moving(m.t1 + 1.0)  # the wheels turn: no zero-velocity update for a second
        verdict = self._judge(m, v, v_pre)
        if verdict is None:
            self._bad = 0
            if self.refused is not None:
                self._good += 1
                if self._good < self.w.agree_to_resume:
                    return "refused"
                self.refused, self._good = None, 0
            self._queue.append((m.t_mid, m.speed))
            return "used"
        self._good = 0
        self._bad += 1
        if self._bad >= self.w.refuse_after and self.refused is None:
            self.refused = verdict
        return verdict

    def _judge(self, m: WheelMotion, v: float, v_pre: float) -> str | None:
        """None when the wheel speed v (scaled, m/s; v_pre the preintegrated speed at its middle) agrees with the
        filter and the gyro, else why not."""
        gyro_rate = self._yaw_rate(m.t0, m.t1) if m.yaw_rate is not None else None
        if m.yaw_rate is not None and gyro_rate is not None and abs(m.yaw_rate - gyro_rate) > self.w.yaw_rate_gate_rps:
            return "slip"
        ukf = self.timeline.ukf
        v_filter = v_pre + float(ukf.x[3])
        if abs(v) < STANDING_MPS and self.zero.active:
            return None  # the filter took the last frame for a stop too
        own = self.w.speed_sigma_mps**2 + self.scale.var * m.speed**2
        # a refused source must agree on its own noise: the filter's speed variance grows while nothing aids it
        var = own if self.refused is not None else float(ukf.P[3, 3]) + own
        z = v - v_filter
        if z * z <= self.w.gate_chi2 * var:
            return None
        if abs(v) < STANDING_MPS:
            return "stuck"
        return "slip" if abs(v) > abs(v_filter) else "disagrees"

    # ------------------------------------------------------------------ the frames
    def open_frame(self, tick: Tick, heading_mid: float) -> WheelSpeed | None:
        """The correction for the new frame `tick` (before its advance): the kept wheel speeds whose middle lies
        before its end, fresh enough, as one measurement of the speed error at its end; None without one. Also
        carries the scale's raw-wheel displacement (heading_mid: the frame's mean heading, ENU rad)."""
        t_end = tick.t
        due = [(t, v) for t, v in self._queue if t <= t_end]
        self._queue = [(t, v) for t, v in self._queue if t > t_end]
        fresh = [(t, v) for t, v in due if t_end - t <= self.w.max_age_s and self.refused is None]
        dvs = []
        for t, v_raw in fresh:
            v_pre = self._speed_at(t)
            if v_pre is not None:
                dvs.append(self.scale.s * v_raw - v_pre)
        if not dvs:
            self.scale.advance(tick, 0.0, heading_mid)
            return None
        raw = sum(v for _, v in fresh) / len(fresh)
        self.scale.advance(tick, raw * tick.inc.dt, heading_mid)
        self.used_t = t_end
        sigma = math.sqrt(self.w.speed_sigma_mps**2 + self.scale.var * raw * raw)
        self.zero.seen(sigma)  # the speed was just observed: a stop must now be one the wheels allow
        return WheelSpeed(sum(dvs) / len(dvs), sigma)

    def in_use(self, t: float) -> bool:
        """Whether the wheel speed steers the speed estimate at autopilot time t (fused within IN_USE_S)."""
        return self.refused is None and t - self.used_t <= IN_USE_S
