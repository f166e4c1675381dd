"""taco+'s closed-loop safety guard: the estimate against the IMU-only track since the last accepted fix
(`imu_check.UnaidedTrack`); on disagreement the reported variance covers it, zero-velocity updates are held off
and a speed one took away is given back. A part of taco+ (estimator.py), acting on the Localiser's timeline.

World frame ENU metres, speeds m/s, times autopilot seconds.
"""

from __future__ import annotations

import math

import numpy as np

from taco_mav.core.timeline import Timeline
from taco_mav.core.plus.imu_check import UnaidedTrack
from taco_mav.core.plus.lock import LockMonitor
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.types import horizontal_sigma


class SafetyGuard:
    """The guard for the Localiser's `timeline` (plus.guard): it owns the unaided track and what it added to the
    filter's variance; lock events go to `lock`."""

    def __init__(self, timeline: Timeline, q: PlusParams, lock: LockMonitor) -> None:
        self.timeline, self.q, self.lock = timeline, q, lock
        self.unaided = UnaidedTrack(q.guard_k, q.guard_floor_m, q.imu_accel_sigma_mps2)
        self.added = 0.0  # position variance the guard added since the last accepted fix, m^2
        self.flagged = False  # the estimate and the unaided track disagree (until a fix settles it)
        self.zupt_holdoff_until = -math.inf  # no zero-velocity update before this time, s
        self.zupt_since_reset = False  # a zero-velocity update since the IMU-only track was reset

    def reset(self) -> None:
        """Restart the IMU-only track at the current estimate (start-up, accepted fix)."""
        tl = self.timeline
        est, P = tl.estimate(0.0), tl.ukf.P
        self.unaided.reset(tl.t, (float(est.xy[0]), float(est.xy[1])), float(tl.pre.speed),
                           float(tl.ukf.x[4]), horizontal_sigma(P), math.sqrt(max(float(P[3, 3]), 0.0)),
                           math.sqrt(max(float(P[4, 4]), 0.0)))
        self.added = 0.0
        self.zupt_since_reset = False
        if self.flagged:
            self.flagged = False
            self.lock.note(tl.t, "imu_agrees", "a fix settled the disagreement")

    def add_imu(self, t: float, accel_fwd: float, theta: float) -> None:
        """One fresh IMU sample for the unaided track (time s, forward specific force m/s^2, ENU heading rad)."""
        self.unaided.add(t, accel_fwd, theta, self.timeline.p.imu.allow_reverse)

    def distrust_zupt(self) -> None:
        """Evidence that the estimate lost the motion (the IMU-only track or the fixes disagree): hold
        zero-velocity updates off, and when one happened since the last accepted fix while the IMU alone still
        has the vehicle moving, give the IMU's speed back (a smooth cruise was taken for a stop) with a speed
        variance that lets the next fixes correct it."""
        tl = self.timeline
        self.zupt_holdoff_until = tl.t + self.q.guard_zupt_holdoff_s
        gap = self.unaided.v - float(tl.pre.speed)
        if self.zupt_since_reset and gap > 3.0 * self.unaided.sigma_speed() + self.q.zupt_speed_max_mps:
            tl.pre.speed = self.unaided.v
            self.zupt_since_reset = False
            self.speed_variance_at_least(gap * gap)
            self.lock.note(tl.t, "speed_restored", f"a stop was wrong: speed {gap:+.1f} m/s from the IMU")

    def speed_variance_at_least(self, var: float) -> None:
        """Raise the speed-error variance to at least `var` ((m/s)^2), in the filter and in the last history
        frame (a rewind there starts from it)."""
        tl = self.timeline
        x, P = tl.ukf.get_state()
        P[3, 3] = max(float(P[3, 3]), var)
        tl.ukf.set_state(x, P)
        if tl.history:
            tl.history[-1].P = P.copy()

    def check(self) -> None:
        """Each frame: the estimate against the IMU-only track (module imu_check). On disagreement keep the
        horizontal variance at least the disagreement squared, the speed variance at least the speed gap
        squared, and hold zero-velocity updates off."""
        tl = self.timeline
        est, P = tl.estimate(0.0), tl.ukf.P
        s0 = self.unaided.sigma_xy0
        own = math.sqrt(max(horizontal_sigma(P) ** 2 - self.added - s0 * s0, 0.0))
        bad = self.unaided.check((float(est.xy[0]), float(est.xy[1])), float(est.speed), own)
        if bad is None:
            return
        self.distrust_zupt()
        x, P = tl.ukf.get_state()
        lo = float(np.linalg.eigvalsh(P[:2, :2]).min())
        add = max(bad.distance_m**2 - lo, 0.0)
        P[:2, :2] += add * np.eye(2)
        tl.ukf.set_state(x, P)
        self.added += add
        self.speed_variance_at_least(bad.speed_gap_mps**2)
        if not self.flagged:
            self.flagged = True
            self.lock.note(tl.t, "imu_disagrees", f"estimate {bad.distance_m:.1f} m from the IMU-only track "
                           f"after {bad.tau_s:.0f} s (1-sigma {bad.sigma_m:.1f} m, speed gap "
                           f"{bad.speed_gap_mps:+.1f} m/s): accuracy widened")
