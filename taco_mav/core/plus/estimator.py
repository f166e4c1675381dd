"""taco+ as the Localiser's estimator (`make_plus`): the paper's heuristics replaced where they lose lock or
overwrite the state, as parts sharing the lock state machine (lock.py), held answers (answer_hold.py), the safety
guard (safety_guard.py), stops (zero_velocity.py), the camera speed's scale error (speed_scale.py), the wheels'
speed and its learnt scale (wheel_speed.py, wheel_scale.py: only with a profile's wheels), the fix noise
and reported-accuracy factors (noise.py) and the running tallies (progress.py): the filter (filter.py), the
trigger (trigger.py), what an answer does (fix_policy.py), what a real GNSS reading does (gnss.py), the reported
accuracy (report.py) and the aiding (aiding.py). Paper mode (`paper.make_paper`) is untouched.

State: x, y (ENU m), theta (ENU rad), dv (speed error, m/s), b (forward accelerometer bias, m/s^2), optionally
beta (compass bias, rad) and the map's offset (ENU m). After every frame the speed error is moved into the
preintegrator (error-state feedback, `PlusAids.feedback`), so `estimate().speed` is the corrected speed; the
amount is kept on the frame (a `SpeedFeedback` correction) so a replay after a late fix subtracts it again.
"""

from __future__ import annotations

from taco_mav.core.estimator import EstimatorParts
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.aiding import PlusAids
from taco_mav.core.plus.answer_hold import AnswerHold
from taco_mav.core.plus.filter import PlusFilter
from taco_mav.core.plus.fix_policy import PlusFixPolicy
from taco_mav.core.plus.gnss import KalmanGnss
from taco_mav.core.plus.lock import LockMonitor
from taco_mav.core.plus.noise import FixNoiseScale, VarianceFactor
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.progress import Progress
from taco_mav.core.plus.report import PlusReport
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.speed_scale import ScaleConsider
from taco_mav.core.plus.trigger import PlusTrigger
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.queries import QueryDesk
from taco_mav.core.timeline import Timeline

__all__ = ["make_plus"]


def make_plus(timeline: Timeline, desk: QueryDesk, gnss: GnssFusion, params: LocaliserParams,
              q: PlusParams) -> EstimatorParts:
    """taco+'s estimator on the Localiser's `timeline`, `desk` and `gnss`, with q the taco+ parameters
    (params.plus)."""
    t0 = timeline.t
    timeline.pre.gyro_heading = q.gyro_heading
    lock = LockMonitor(q.lost_after, q.lost_after_s, q.capture_radius_m, q.confirm_fixes, last_accept_t=t0)
    fix_scale = FixNoiseScale(q.fix_scale_min, q.fix_scale_max, q.fix_scale_window,
                              s2=min(max(q.fix_scale_initial, q.fix_scale_min), q.fix_scale_max) ** 2)
    report_factor = VarianceFactor(q.report_factor_min, q.report_factor_max, q.report_window)
    guard = SafetyGuard(timeline, q, lock)
    zero = ZeroVelocity(timeline, q, guard, t0)
    answers = AnswerHold(timeline, q, lock, report_factor, guard)
    scale = ScaleConsider(q.camera_speed_scale_sigma)  # the camera speed's scale error (a consider term)
    progress = Progress()
    aids = PlusAids(timeline, gnss, params, q, lock=lock, progress=progress, guard=guard, zero=zero, scale=scale,
                    answers=answers)
    return EstimatorParts(
        filter=PlusFilter(params, q),
        trigger=PlusTrigger(timeline, desk, gnss, params, q, lock=lock, progress=progress, answers=answers,
                            zero=zero, wheels=aids.wheels),
        fixes=PlusFixPolicy(timeline, desk, params, q, gnss=gnss, lock=lock, progress=progress, answers=answers,
                            fix_scale=fix_scale, report_factor=report_factor, scale=scale, zero=zero, guard=guard,
                            feedback=aids.feedback, wheels=aids.wheels),
        gnss=KalmanGnss(timeline, q, zero, guard, aids.feedback),
        report=PlusReport(timeline, gnss, q, lock=lock, guard=guard, report_factor=report_factor, scale=scale,
                          answers=answers, fix_scale=fix_scale, zero=zero, wheels=aids.wheels),
        aids=aids)
