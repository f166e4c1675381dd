"""taco+'s closed-loop safety guard (issue 19): the estimate against the IMU-only track since the last
accepted fix (`imu_check.UnaidedTrack`); on disagreement the reported variance covers it, zero-velocity updates
are held off and a speed one took away is given back. A mixin of `PlusLocaliser` (which initialises the
attributes used here and calls `_reset_unaided` / `_guard` / `_distrust_zupt`).

World frame ENU metres, speeds m/s, times autopilot seconds.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from taco_mav.core.types import horizontal_sigma


class SafetyGuardMixin:
    """The guard's methods for PlusLocaliser."""

    q: Any
    t: float
    ukf: Any
    pre: Any
    lock: Any
    unaided: Any
    _history: Any
    _guard_added: float
    _guard_flagged: bool
    _zupt_holdoff_until: float
    _zupt_since_reset: bool

    def _reset_unaided(self) -> None:
        """Restart the IMU-only track at the current estimate (start-up, accepted fix)."""
        est, P = super().estimate(), self.ukf.P
        self.unaided.reset(self.t, (float(est.xy[0]), float(est.xy[1])), float(self.pre.speed), float(self.ukf.x[4]),
                           horizontal_sigma(P), math.sqrt(max(float(P[3, 3]), 0.0)),
                           math.sqrt(max(float(P[4, 4]), 0.0)))
        self._guard_added = 0.0
        self._zupt_since_reset = False
        if self._guard_flagged:
            self._guard_flagged = False
            self.lock.note(self.t, "imu_agrees", "a fix settled the disagreement")

    def _distrust_zupt(self) -> None:
        """Evidence that the estimate lost the motion (the IMU-only track or the fixes disagree): hold
        zero-velocity updates off, and when one happened since the last accepted fix while the IMU alone still
        has the vehicle moving, give the IMU's speed back (a smooth cruise was taken for a stop) with a speed
        variance that lets the next fixes correct it."""
        self._zupt_holdoff_until = self.t + self.q.guard_zupt_holdoff_s
        gap = self.unaided.v - float(self.pre.speed)
        if self._zupt_since_reset and gap > 3.0 * self.unaided.sigma_v0 + self.q.zupt_speed_max_mps:
            self.pre.speed = self.unaided.v
            self._zupt_since_reset = False
            self._speed_variance_at_least(gap * gap)
            self.lock.note(self.t, "speed_restored", f"a stop was wrong: speed {gap:+.1f} m/s from the IMU")

    def _speed_variance_at_least(self, var: float) -> None:
        """Raise the speed-error variance to at least `var` ((m/s)^2), in the filter and in the last history
        frame (a rewind there starts from it)."""
        x, P = self.ukf.get_state()
        P[3, 3] = max(float(P[3, 3]), var)
        self.ukf.set_state(x, P)
        if self._history:
            self._history[-1].P = P.copy()

    def _guard(self) -> None:
        """Each frame: the estimate against the IMU-only track (module imu_check). On disagreement keep the
        horizontal variance at least the disagreement squared, the speed variance at least the speed gap
        squared, and hold zero-velocity updates off."""
        est, P = super().estimate(), self.ukf.P
        s0 = self.unaided.sigma_xy0
        own = math.sqrt(max(horizontal_sigma(P) ** 2 - self._guard_added - s0 * s0, 0.0))
        bad = self.unaided.check((float(est.xy[0]), float(est.xy[1])), float(est.speed), own)
        if bad is None:
            return
        self._distrust_zupt()
        x, P = self.ukf.get_state()
        lo = float(np.linalg.eigvalsh(P[:2, :2]).min())
        add = max(bad.distance_m**2 - lo, 0.0)
        P[:2, :2] += add * np.eye(2)
        self.ukf.set_state(x, P)
        self._guard_added += add
        self._speed_variance_at_least(bad.speed_gap_mps**2)
        if not self._guard_flagged:
            self._guard_flagged = True
            self.lock.note(self.t, "imu_disagrees", f"estimate {bad.distance_m:.1f} m from the IMU-only track "
                           f"after {bad.tau_s:.0f} s (1-sigma {bad.sigma_m:.1f} m, speed gap "
                           f"{bad.speed_gap_mps:+.1f} m/s): accuracy widened")
