"""What an answer does in taco+: consensus over the crops' candidates (search.py), the answer check while lock is
lost (answer_check.py), a weak answer deferred while the filter can wait, the chi-square innovation gate against
the track (tighter for an uncorroborated answer), a jump held until a second answer confirms it (answer_hold.py),
the fix noise learnt from earlier fixes (noise.py), the camera speed's and the wheels' scale errors entering the
filter where the fix can take it out (speed_scale.py, wheel_scale.py; the fix also teaches the wheels' scale), and the answer's rotation as a measurement of the true heading. Every
answered trigger without an accepted fix counts towards loss of lock (lock.py).

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from taco_mav.core.answer_check import credible, supported
from taco_mav.core.frames import FixOutcome, FixReason, Tick
from taco_mav.core.gate import yaw_residual
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.answer_hold import AnswerHold
from taco_mav.core.plus.lock import LockMonitor, LockState
from taco_mav.core.plus.noise import FixNoiseScale, VarianceFactor
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.progress import Progress
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.search import consensus, defer_answer
from taco_mav.core.plus.speed_scale import ScaleConsider
from taco_mav.core.plus.wheel_speed import WheelAiding
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.queries import Answering, QueryDesk
from taco_mav.core.search import fix_position
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import MatchResult, horizontal_sigma
from taco_mav.core.ukf import fix_covariance, weight_sigmas

__all__ = ["PlusFixPolicy"]


class PlusFixPolicy:
    """taco+'s answers on the Localiser's `timeline` and `desk` (see the module docstring); `feedback` moves the
    speed error into the preintegrator after a fix (`PlusAids.feedback`)."""

    def __init__(self, timeline: Timeline, desk: QueryDesk, params: LocaliserParams, q: PlusParams, *,
                 lock: LockMonitor, progress: Progress, answers: AnswerHold, fix_scale: FixNoiseScale,
                 report_factor: VarianceFactor, scale: ScaleConsider, zero: ZeroVelocity, guard: SafetyGuard,
                 feedback: Callable[[Tick], None], wheels: WheelAiding | None = None) -> None:
        self.timeline, self.desk, self.p, self.q = timeline, desk, params, q
        self.lock, self.progress, self.answers, self.fix_scale = lock, progress, answers, fix_scale
        self.report_factor, self.scale, self.zero, self.guard = report_factor, scale, zero, guard
        self._feedback, self.wheels = feedback, wheels

    def judge(self, answer: Answering, results: Sequence[MatchResult | None]) -> FixOutcome:
        """Consensus over the candidates, the chi-square innovation gate, held answers and the lock state machine
        (every answered trigger without an accepted fix counts towards loss of lock)."""
        tl, answers = self.timeline, self.answers
        q, now, p, qp = answer.query, answer.now, self.p, self.q
        self.progress.last_answer_t = now
        weights = answer.weights
        xy = np.full((len(results), 2), np.nan)
        psi = np.full(len(results), np.nan)
        for k, r in enumerate(results):
            if r is not None:
                xy[k] = fix_position(q.crop_centres[k], q.heading, r.t, p.camera_lever_fwd_left_m)
                psi[k] = yaw_residual(r.R)
        w = np.array(weights)
        finite = np.isfinite(xy).all(axis=1) & np.isfinite(psi) & np.isfinite(w) & (w > 0)
        with np.errstate(invalid="ignore"):
            yaw_ok = (np.abs(psi) <= p.gate.yaw_residual_max_rad) | (not p.gate.enabled)
        lost = self.lock.state is LockState.LOST
        strong = finite & yaw_ok & (w >= (qp.recover_w_min if lost else qp.w_min))
        # while lock is lost no innovation gate stands between an answer and a relocalisation: the answer check
        # does (answer_check.py); while locked the gate against the track does
        usable = strong & credible(results, p.answer) if lost else strong
        c = consensus(np.nan_to_num(xy), w, usable, qp.consensus_radius_m, qp.consensus_weight_power)
        self.desk.answered(q, now)
        if c is None:
            reason = (FixReason.NONFINITE if not finite.any() else FixReason.YAW_GATE if not (finite & yaw_ok).any()
                      else FixReason.AT_CHANCE if strong.any() else FixReason.WEAK)
            answers.failed(reason, 0.0, self.progress.odo)
            return answer.refused(reason)
        k, z = c.index, c.xy
        if lost and not supported(xy, k, q.crop_centres, p.answer):  # one or two crops of five: the crops' own
            answers.failed(FixReason.AT_CHANCE, 0.0, self.progress.odo)
            return answer.refused(FixReason.AT_CHANCE, chosen=k, xy=z, yaw_residual=psi[k])
        tick = tl.capture_tick(q.capture_t)
        if tick is None:
            return answer.refused(FixReason.STALE, chosen=k, xy=z, yaw_residual=psi[k])
        if self._defer(c.weight, tick.P):  # weak, and the filter can wait for a better one: ask again
            return answer.refused(FixReason.DEFERRED, chosen=k, xy=z, yaw_residual=psi[k])
        # the matcher's w mapped as in the paper (plus.fix_isotropic: both sigmas their mean)
        s_f0, s_l0 = weight_sigmas(p.ukf, c.weight, False if qp.fix_isotropic else None)
        sc = self.fix_scale.scale if qp.adaptive_fix_noise else 1.0  # what earlier fixes taught
        s_f, s_l = sc * s_f0, sc * s_l0
        pred, Pz = tl.ukf.fix_prediction(tick.x, tick.P)  # position (+ the map's offset), its covariance
        scale_cov = self.scale.covariance_at(tick) if qp.speed_scale_consider else None
        if scale_cov is not None:  # the camera speed's scale error since the last pin (speed_scale.py)
            Pz = Pz + scale_cov
        Pz_other = Pz  # all but the wheels' scale error: the noise of the scale's measurement below
        wheel_cov = self.wheels.scale.covariance_at(tick) if self.wheels is not None else None
        if wheel_cov is not None:  # the wheels' scale error since the last fix (wheel_scale.py), likewise
            Pz = Pz + wheel_cov
        innov = z - pred
        jump = float(np.linalg.norm(innov))
        nis = float(innov @ np.linalg.solve(Pz + fix_covariance(float(tick.x[2]), s_f, s_l), innov))
        state = self.lock.state
        if state is LockState.LOST:
            gate = qp.recover_chi2_gate if qp.recover_chi2_gate > 0.0 else math.inf  # under the widened P
        else:
            gate = qp.chi2_gate if c.support > 1 else qp.chi2_gate_single
        if nis > gate:
            answers.failed(FixReason.INNOVATION_GATE, jump, self.progress.odo, innov if c.weight >= qp.guard_w_min else None)
            return answer.refused(FixReason.INNOVATION_GATE, chosen=k, xy=z, yaw_residual=psi[k], sigma_fwd=s_f,
                                  sigma_lat=s_l, nis=nis)
        held = answers.hold(state, innov, jump, Pz, now, self.progress.odo, now - q.capture_t, tick.track_unit)
        if held == "hold":
            answers.failed(FixReason.UNCONFIRMED, jump, self.progress.odo)
            return answer.refused(FixReason.UNCONFIRMED, chosen=k, xy=z, yaw_residual=psi[k], sigma_fwd=s_f,
                                  sigma_lat=s_l, nis=nis)
        if state is LockState.LOST or held == "confirmed":  # relocalise: the candidate replaces the position
            tick.P = tick.P.copy()  # (the jump enters P)
            tick.P[:2, :2] += jump * jump * np.eye(2)
        if scale_cov is not None:  # ... enters the filter where the fix can take it out
            tick.P = tick.P.copy()
            tick.P[:2, :2] += scale_cov
        if wheel_cov is not None:
            tick.P = tick.P.copy()
            tick.P[:2, :2] += wheel_cov
        answers.held = []
        learn = state is LockState.LOCKED and held is None
        if qp.adaptive_fix_noise and learn:  # learn from this fix for the next ones
            self.fix_scale.update(innov, Pz, fix_covariance(float(tick.x[2]), s_f0, s_l0))
        # the answer's rotation measures the true heading at capture (plus.fix_yaw_sigma_rad; 0: gate only)
        heading = (q.heading + float(psi[k]), qp.fix_yaw_sigma_rad) if qp.fix_yaw_sigma_rad > 0.0 else None
        if self.wheels is not None:  # what this fix says of the wheels' scale (wheel_scale.py)
            self.wheels.scale.fix(tick, innov, Pz_other + fix_covariance(float(tick.x[2]), s_f, s_l))
        tl.fix(tick, z, s_f, s_l, heading)
        self.scale.pin(tick)
        pr = self.progress
        pr.odo_at_fix = max(pr.odo_at_fix, pr.odo_at_query)  # the query was planned at its capture
        if learn:
            self.report_factor.update(nis)
        # a confirmed jump is a relocalisation: half of it stays in P until confirm_fixes later fixes agree
        answers.settle_lock(LockState.LOST if held == "confirmed" else state, jump, s_f, s_l)
        if tl.history:
            self._feedback(tl.history[-1])
        answers.accepted()
        self.progress.deferred = 0
        self.zero.seen(math.sqrt(max(float(tl.ukf.P[3, 3]), 0.0)))
        if self.q.guard:
            self.guard.reset()
        return answer.accepted(chosen=k, xy=z, yaw_residual=psi[k], sigma_fwd=s_f, sigma_lat=s_l, nis=nis)

    def _defer(self, w: float, P: np.ndarray) -> bool:
        """Whether to leave a weak answer (consensus weight w) unused and ask again (plus.defer_answer)."""
        healthy = self.lock.state is LockState.LOCKED and not self.guard.flagged
        pr = self.progress
        if defer_answer(w, pr.deferred, healthy, horizontal_sigma(P), pr.odo - pr.odo_at_fix, self.q):
            pr.deferred += 1
            return True
        return False
