"""What an answer does in taco+: consensus over the crops' candidates (search.py), the answer check while lock is
lost (answer_check.py), a weak answer deferred while the filter can wait, the chi-square innovation gate against
the track (tighter for an uncorroborated answer), every answer refused while the GNSS readings refute the camera
(gnss/guard.py: it never agreed with them and its last checks disagreed), a jump held until a second answer
confirms it (answer_hold.py), the fix noise learnt from earlier fixes (noise.py), the camera speed's and the
wheels' scale errors entering the filter where the fix can take it out (speed_scale.py, wheel_scale.py; the fix
also teaches the wheels' scale), and the answer's rotation as a measurement of the true heading. Every answered
trigger without an accepted fix counts towards loss of lock (lock.py).

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from taco_mav.core.answer_check import credible, supported
from taco_mav.core.frames import FixOutcome, FixReason, Tick
from taco_mav.core.gate import yaw_residual
from taco_mav.core.gnss.fusion import GnssFusion
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
from taco_mav.core.types import FixQuery, MatchResult, horizontal_sigma
from taco_mav.core.ukf import fix_covariance, weight_sigmas

__all__ = ["PlusFixPolicy"]


@dataclass(frozen=True)
class _Candidates:
    """Every crop's answer as a fix: xy (K, 2) ENU m, psi (K,) yaw residual rad, w (K,) weights, and per crop
    whether it is finite, passes the yaw gate, is strong enough and usable; lost: lock was lost when judged."""

    xy: np.ndarray
    psi: np.ndarray
    w: np.ndarray
    finite: np.ndarray
    yaw_ok: np.ndarray
    strong: np.ndarray
    usable: np.ndarray
    lost: bool

    def why_none(self) -> FixReason:
        """Why no consensus formed."""
        if not self.finite.any():
            return FixReason.NONFINITE
        if not (self.finite & self.yaw_ok).any():
            return FixReason.YAW_GATE
        return FixReason.AT_CHANCE if self.strong.any() else FixReason.WEAK


@dataclass(frozen=True)
class _Innovation:
    """A consensus fix against the prediction: the paper's sigmas (s_f0, s_l0, m) and those used (scaled by what
    earlier fixes taught), the innovation covariance Pz (m^2) and Pz_other (without the wheels' scale error), the
    scale terms added to it (m^2, or None), the innovation (ENU m), its length `jump` (m) and its NIS."""

    s_f0: float
    s_l0: float
    s_f: float
    s_l: float
    Pz: np.ndarray
    Pz_other: np.ndarray
    scale_cov: np.ndarray | None
    wheel_cov: np.ndarray | None
    innov: np.ndarray
    jump: float
    nis: float


class PlusFixPolicy:
    """taco+'s answers on the Localiser's `timeline` and `desk` (see the module docstring); `feedback` moves the
    speed error into the preintegrator after a fix (`PlusAids.feedback`); `gnss` says whether its readings refute
    the camera."""

    def __init__(self, timeline: Timeline, desk: QueryDesk, params: LocaliserParams, q: PlusParams, *,
                 gnss: GnssFusion, lock: LockMonitor, progress: Progress, answers: AnswerHold,
                 fix_scale: FixNoiseScale, report_factor: VarianceFactor, scale: ScaleConsider, zero: ZeroVelocity,
                 guard: SafetyGuard, feedback: Callable[[Tick], None], wheels: WheelAiding | None = None) -> None:
        self.timeline, self.desk, self.p, self.q = timeline, desk, params, q
        self.lock, self.progress, self.answers, self.fix_scale = lock, progress, answers, fix_scale
        self.report_factor, self.scale, self.zero, self.guard = report_factor, scale, zero, guard
        self._feedback, self.wheels, self.gnss = feedback, wheels, gnss
        self._refuted = False  # the refutation as last noted (a lock note when it changes)

    def judge(self, answer: Answering, results: Sequence[MatchResult | None]) -> FixOutcome:
        """Consensus over the candidates, the chi-square innovation gate, held answers and the lock state machine
        (every answered trigger without an accepted fix counts towards loss of lock)."""
        q, now, answers, odo = answer.query, answer.now, self.answers, self.progress.odo
        self.progress.last_answer_t = now
        cand = self._candidates(q, results, np.array(answer.weights))
        c = consensus(np.nan_to_num(cand.xy), cand.w, cand.usable, self.q.consensus_radius_m,
                      self.q.consensus_weight_power)
        self.desk.answered(q, now)
        if c is None:
            reason = cand.why_none()
            answers.failed(reason, 0.0, odo)
            return answer.refused(reason)
        k, z = c.index, c.xy
        found = dict(chosen=k, xy=z, yaw_residual=cand.psi[k])
        if cand.lost and not supported(cand.xy, k, q.crop_centres, self.p.answer):  # one or two crops of five
            answers.failed(FixReason.AT_CHANCE, 0.0, odo)
            return answer.refused(FixReason.AT_CHANCE, **found)
        tick = self.timeline.capture_tick(q.capture_t)
        if tick is None:
            return answer.refused(FixReason.STALE, **found)
        if self._defer(c.weight, tick.P):  # weak, and the filter can wait for a better one: ask again
            return answer.refused(FixReason.DEFERRED, **found)
        inn = self._innovation(tick, z, c.weight)
        state = self.lock.state
        if state is LockState.LOST:
            gate = self.q.recover_chi2_gate if self.q.recover_chi2_gate > 0.0 else math.inf  # under the widened P
        else:
            gate = self.q.chi2_gate if c.support > 1 else self.q.chi2_gate_single
        figures = dict(found, sigma_fwd=inn.s_f, sigma_lat=inn.s_l, nis=inn.nis)
        if self._refutes():
            answers.failed(FixReason.REFUTED, inn.jump, odo)
            return answer.refused(FixReason.REFUTED, **figures)
        if inn.nis > gate:
            answers.failed(FixReason.INNOVATION_GATE, inn.jump, odo,
                           inn.innov if c.weight >= self.q.guard_w_min else None)
            return answer.refused(FixReason.INNOVATION_GATE, **figures)
        held = answers.hold(state, inn.innov, inn.jump, inn.Pz, now, odo, now - q.capture_t, tick.track_unit)
        if held == "hold":
            answers.failed(FixReason.UNCONFIRMED, inn.jump, odo)
            return answer.refused(FixReason.UNCONFIRMED, **figures)
        self._fuse(tick, z, q.heading + float(cand.psi[k]), inn, state, held)
        return answer.accepted(**figures)

    def _refutes(self) -> bool:
        """Whether the GNSS readings refute the camera now (`GnssFusion.camera_refuted`); a lock note when that
        starts and when it ends."""
        refuted = self.gnss.camera_refuted
        if refuted != self._refuted:
            self._refuted = refuted
            t = self.timeline.t
            if refuted:
                self.lock.note(t, "camera_refuted", "never agreed with GNSS")
            else:
                self.lock.note(t, "camera_agrees", "with GNSS again")
        return refuted

    def _candidates(self, q: FixQuery, results: Sequence[MatchResult | None], w: np.ndarray) -> _Candidates:
        """Every crop's fix (ENU m) and yaw residual (rad), and which are finite, pass the yaw gate, are strong
        enough for the lock state (plus.w_min, recover_w_min) and usable (while lock is lost, also credible)."""
        p, qp = self.p, self.q
        xy = np.full((len(results), 2), np.nan)
        psi = np.full(len(results), np.nan)
        for k, r in enumerate(results):
            if r is not None:
                xy[k] = fix_position(q.crop_centres[k], q.heading, r.t, p.camera_lever_fwd_left_m)
                psi[k] = yaw_residual(r.R)
        finite = np.isfinite(xy).all(axis=1) & np.isfinite(psi) & np.isfinite(w) & (w > 0)
        with np.errstate(invalid="ignore"):
            yaw_ok = (np.abs(psi) <= p.gate.yaw_residual_max_rad) | (not p.gate.enabled)
        lost = self.lock.state is LockState.LOST
        strong = finite & yaw_ok & (w >= (qp.recover_w_min if lost else qp.w_min))
        # while lock is lost no innovation gate stands between an answer and a relocalisation: the answer check
        # does (answer_check.py); while locked the gate against the track does
        usable = strong & credible(results, p.answer) if lost else strong
        return _Candidates(xy, psi, w, finite, yaw_ok, strong, usable, lost)

    def _innovation(self, tick: Tick, z: np.ndarray, weight: float) -> _Innovation:
        """The consensus fix z (ENU m, weight `weight`) against the filter's prediction at its capture frame."""
        qp = self.q
        # the matcher's w mapped as in the paper (plus.fix_isotropic: both sigmas their mean)
        s_f0, s_l0 = weight_sigmas(self.p.ukf, weight, False if qp.fix_isotropic else None)
        sc = self.fix_scale.scale if qp.adaptive_fix_noise else 1.0  # what earlier fixes taught
        s_f, s_l = sc * s_f0, sc * s_l0
        pred, Pz = self.timeline.ukf.fix_prediction(tick.x, tick.P)  # position (+ the map's offset), covariance
        scale_cov = self.scale.covariance_at(tick) if qp.speed_scale_consider else None
        if scale_cov is not None:  # the camera speed's scale error since the last pin (speed_scale.py)
            Pz = Pz + scale_cov
        Pz_other = Pz  # all but the wheels' scale error: the noise of the scale's measurement
        wheel_cov = self.wheels.scale.covariance_at(tick) if self.wheels is not None else None
        if wheel_cov is not None:  # the wheels' scale error since the last fix (wheel_scale.py), likewise
            Pz = Pz + wheel_cov
        innov = z - pred
        nis = float(innov @ np.linalg.solve(Pz + fix_covariance(float(tick.x[2]), s_f, s_l), innov))
        return _Innovation(s_f0, s_l0, s_f, s_l, Pz, Pz_other, scale_cov, wheel_cov, innov,
                           float(np.linalg.norm(innov)), nis)

    def _fuse(self, tick: Tick, z: np.ndarray, true_heading: float, inn: _Innovation, state: LockState,
              held: str | None) -> None:
        """Fuse the fix z (ENU m) at its capture frame `tick`; true_heading: the heading its rotation measures,
        ENU rad; held: the answer hold's verdict ("confirmed": a relocalisation, None: an ordinary fix)."""
        qp, tl, answers = self.q, self.timeline, self.answers
        if state is LockState.LOST or held == "confirmed":  # relocalise: the candidate replaces the position
            tick.P = tick.P.copy()  # (the jump enters P)
            tick.P[:2, :2] += inn.jump * inn.jump * np.eye(2)
        if inn.scale_cov is not None:  # ... enters the filter where the fix can take it out
            tick.P = tick.P.copy()
            tick.P[:2, :2] += inn.scale_cov
        if inn.wheel_cov is not None:
            tick.P = tick.P.copy()
            tick.P[:2, :2] += inn.wheel_cov
        answers.held = []
        learn = state is LockState.LOCKED and held is None
        if qp.adaptive_fix_noise and learn:  # learn from this fix for the next ones
            self.fix_scale.update(inn.innov, inn.Pz, fix_covariance(float(tick.x[2]), inn.s_f0, inn.s_l0))
        # the answer's rotation measures the true heading at capture (plus.fix_yaw_sigma_rad; 0: gate only)
        heading = (true_heading, qp.fix_yaw_sigma_rad) if qp.fix_yaw_sigma_rad > 0.0 else None
        if self.wheels is not None:  # what this fix says of the wheels' scale (wheel_scale.py)
            self.wheels.scale.fix(tick, inn.innov, inn.Pz_other + fix_covariance(float(tick.x[2]), inn.s_f, inn.s_l))
        tl.fix(tick, z, inn.s_f, inn.s_l, heading)
        self.scale.pin(tick)
        pr = self.progress
        pr.odo_at_fix = max(pr.odo_at_fix, pr.odo_at_query)  # the query was planned at its capture
        if learn:
            self.report_factor.update(inn.nis)
        # a confirmed jump is a relocalisation: half of it stays in P until confirm_fixes later fixes agree
        answers.settle_lock(LockState.LOST if held == "confirmed" else state, inn.jump, inn.s_f, inn.s_l)
        if tl.history:
            self._feedback(tl.history[-1])
        answers.accepted()
        pr.deferred = 0
        self.zero.seen(math.sqrt(max(float(tl.ukf.P[3, 3]), 0.0)))
        if qp.guard:
            self.guard.reset()

    def _defer(self, w: float, P: np.ndarray) -> bool:
        """Whether to leave a weak answer (consensus weight w) unused and ask again (plus.defer_answer)."""
        healthy = self.lock.state is LockState.LOCKED and not self.guard.flagged
        pr = self.progress
        if defer_answer(w, pr.deferred, healthy, horizontal_sigma(P), pr.odo - pr.odo_at_fix, self.q):
            pr.deferred += 1
            return True
        return False
