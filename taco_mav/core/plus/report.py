"""taco+'s reported accuracy: the fixes' variance factor (noise.py) makes it honest while locked and while the
safety guard agrees, the camera speed's and the wheels' scale errors (speed_scale.py, wheel_scale.py) are added, and rejections that agree keep a
floor under it (answer_hold.py); the taco+ states go in `Estimate.extra`.

Positions ENU metres, covariances m^2.
"""

from __future__ import annotations

import dataclasses

from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.plus.answer_hold import AnswerHold
from taco_mav.core.plus.lock import LockMonitor, LockState
from taco_mav.core.plus.noise import FixNoiseScale, VarianceFactor
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.speed_scale import ScaleConsider
from taco_mav.core.plus.wheel_speed import WheelAiding
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import Estimate

__all__ = ["PlusReport"]


class PlusReport:
    """taco+'s reported accuracy on the Localiser's `timeline` (see the module docstring)."""

    def __init__(self, timeline: Timeline, gnss: GnssFusion, q: PlusParams, *, lock: LockMonitor,
                 guard: SafetyGuard, report_factor: VarianceFactor, scale: ScaleConsider, answers: AnswerHold,
                 fix_scale: FixNoiseScale, zero: ZeroVelocity, wheels: WheelAiding | None = None) -> None:
        self.timeline, self.gnss, self.q = timeline, gnss, q
        self.lock, self.guard, self.report_factor, self.scale = lock, guard, report_factor, scale
        self.answers, self.fix_scale, self.zero, self.wheels = answers, fix_scale, zero, wheels

    def report(self, est: Estimate) -> Estimate:
        """The reported estimate: the fixes' variance factor makes the reported accuracy honest while locked and
        while the safety guard agrees; otherwise the filter's own (widened) covariance is reported as it is.
        Not while a real GNSS is fused: the factor is learnt from camera fixes and says nothing of the
        receiver's wander, which the GNSS update keeps in P. Rejections that agree keep a floor under it."""
        x = self.timeline.ukf.x
        if (self.q.report_calibration and self.lock.state is LockState.LOCKED and not self.guard.flagged
                and not self.gnss.in_use):
            est = dataclasses.replace(est, cov_xy=self.report_factor.factor * est.cov_xy)
        if self.q.speed_scale_consider:
            est = dataclasses.replace(est, cov_xy=est.cov_xy + self.scale.covariance())
        wheel_cov = self.wheels.scale.covariance() if self.wheels is not None else None
        if wheel_cov is not None:
            est = dataclasses.replace(est, cov_xy=est.cov_xy + wheel_cov)
        est = est.floored(self.answers.report_floor_m)
        est.extra.update(lock=self.lock.state.value, speed_error=float(x[3]), accel_bias=float(x[4]),
                         compass_bias=float(x[5]) if len(x) > 5 else 0.0, fix_scale=self.fix_scale.scale,
                         map_offset=[float(v) for v in x[6:8]],
                         stationary=self.zero.active)
        if self.wheels is not None:
            est.extra.update(wheel_scale=self.wheels.scale.s, wheel_scale_sigma=self.wheels.scale.sigma,
                             wheels_refused=self.wheels.refused)
        return est
