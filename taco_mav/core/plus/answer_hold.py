"""taco+'s bookkeeping of answers that were not simply applied (not in the paper): answers held until a second one
agrees (a jump the IMU track does not allow, a recovery candidate), failed triggers (loss of lock, the widened
uncertainty, rejections that agree and so widen the reported accuracy) and the settling of lock after an
applied fix. A part of taco+ (estimator.py), acting on the Localiser's timeline.

World frame ENU metres, times autopilot seconds; a correction is z - x (the fix minus the estimate); odometer
readings (odo) metres driven since the start.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from taco_mav.core.timeline import Timeline
from taco_mav.core.plus.lock import LockMonitor, LockState
from taco_mav.core.plus.noise import VarianceFactor
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.safety_guard import SafetyGuard

# a held answer: (the correction z - x at capture (ENU m), arrival t of the latest agreeing answer, odometer then,
# answers that agreed so far, the integral of the unit heading vector at capture (s, ENU; confirm_speed_error_mps))
Held = tuple[np.ndarray, float, float, int, "tuple[float, float] | None"]


class AnswerHold:
    """Held answers, failures and lock settling for the Localiser's `timeline`, with its `lock`, the reported accuracy's
    `report_factor` and the safety `guard`."""

    def __init__(self, timeline: Timeline, q: PlusParams, lock: LockMonitor, report_factor: VarianceFactor,
                 guard: SafetyGuard) -> None:
        self.timeline, self.q, self.lock, self.report_factor, self.guard = timeline, q, lock, report_factor, guard
        self.held: list[Held] = []  # newest last (jump_confirm_k, recover_confirm)
        self.misses_in_row = 0  # consecutive answered triggers without a fix (off-map answers aside)
        self.last_answer_weak = False  # the last answer had nothing usable (plus.trigger_retry_s asks sooner)
        self.report_floor_m = 0.0  # 1-sigma floor on the reported (not the filter's) position accuracy, m
        self._gate_misses = 0  # consecutive innovation-gate rejections (of at least plus.guard_w_min)
        self._gate_innovs: list[tuple[np.ndarray, float]] = []  # ... their z - x (ENU m) and odometer (m)
        self._floor_m = 0.0  # relocalisation jump kept in P until confirmed, metres (1-sigma)

    def inflate(self, sigma_m: float) -> None:
        """Lock lost: widen the position uncertainty by at least lost_sigma_min_m (and sigma_m), metres."""
        self.timeline.widen(max(self.q.lost_sigma_min_m, sigma_m))

    def accepted(self) -> None:
        """A fix was applied: the runs of failures and the reported floor start again."""
        self._gate_misses = self.misses_in_row = 0
        self.last_answer_weak = False
        self._gate_innovs = []
        self.report_floor_m = 0.0

    def hold(self, state: LockState, innov: np.ndarray, jump: float, P: np.ndarray, t: float, odo: float,
             latency_s: float = 0.0, track_unit: tuple[float, float] | None = None) -> str | None:
        """Whether an answer that passed the weight, yaw and chi-square gates must be confirmed first: None (no:
        apply it), "hold" (kept, not applied) or "confirmed" (it is the confirm_answers-th (lost) or
        jump_confirm_answers-th (not lost; 0: never) answer implying the same correction z - x, to within
        confirm_agree_m plus confirm_agree_per_m of the distance driven since the last of them, within
        confirm_window_s: apply it as a relocalisation). Held: every recovery answer while lock is lost
        (recover_confirm), and an answer that moves the estimate further than jump_confirm_k
        sqrt(lambda_max(P) + jump_confirm_floor_m^2), P the prior position covariance (m^2): a jump the IMU
        track's own uncertainty does not allow. Up to confirm_keep distinct held answers are kept side by side.
        The window stretches to 3 answer latencies (latency_s: arrival minus capture, s), so a matcher slower
        than confirm_window_s per answer can still confirm. They also agree when one correction plus one speed
        error carried along the track explains them (`_explained_by_speed`; track_unit: the integral of the unit
        heading vector up to the answer's capture, s, ENU)."""
        q = self.q
        if state is LockState.LOST:
            if not q.recover_confirm:
                return None
        else:
            if q.jump_confirm_k <= 0.0:
                return None
            lam = max(float(np.linalg.eigvalsh(P[:2, :2]).max()), 0.0)
            if jump <= q.jump_confirm_k * math.sqrt(lam + q.jump_confirm_floor_m**2):
                return None
        window = max(q.confirm_window_s, 3.0 * max(latency_s, 0.0))
        held = [h for h in self.held if t - h[1] <= window]
        near = [(self._disagreement(innov, odo, h[0], h[2]), i) for i, h in enumerate(held)]
        near = [(d, i) for d, i in near if d <= q.confirm_agree_m]
        need = q.confirm_answers if state is LockState.LOST else q.jump_confirm_answers
        if need > 0 and self._explained_by_speed(held, innov, track_unit, need):
            self.held = []
            return "confirmed"
        if near:
            i = min(near)[1]
            n = held[i][3] + 1
            if need > 0 and n >= need:
                self.held = []
                return "confirmed"
            del held[i]
        else:
            n = 1
        self.held = (held + [(np.array(innov, dtype=float), t, odo, n, track_unit)])[-q.confirm_keep:]
        return "hold"

    def _explained_by_speed(self, held: list[Held], innov: np.ndarray, track_unit: tuple[float, float] | None,
                            need: int) -> bool:
        """Whether this answer and need - 1 held ones imply corrections c_i = z - x (ENU m) that one offset e and
        one speed error s (m/s, |s| <= confirm_speed_error_mps) explain as c_i = e + s a_i, each within
        confirm_agree_m; a_i: the integral of the unit heading vector to answer i's capture (s, ENU), so s a_i is
        how far a speed error carries the estimate along the driven track. Needs three answers or more (two
        always fit)."""
        q = self.q
        if q.confirm_speed_error_mps <= 0.0 or need < 3 or track_unit is None:
            return False
        usable = [h for h in held if h[4] is not None]
        for combo in itertools.combinations(usable, need - 1):
            c = np.concatenate([h[0] for h in combo] + [np.asarray(innov, dtype=float)])
            a = np.array([h[4] for h in combo] + [track_unit], dtype=float).ravel()
            A = np.zeros((len(c), 3))
            A[0::2, 0] = A[1::2, 1] = 1.0
            A[:, 2] = a
            sol = np.linalg.lstsq(A, c, rcond=None)[0]
            residual = np.linalg.norm((c - A @ sol).reshape(-1, 2), axis=1)
            if abs(sol[2]) <= q.confirm_speed_error_mps and float(residual.max()) <= q.confirm_agree_m:
                return True
        return False

    def failed(self, reason: str, innovation_m: float, odo: float, innov: np.ndarray | None = None) -> None:
        """An answered trigger without a fix: lock bookkeeping; the uncertainty widens when lock is declared
        lost (half the disagreement, at least lost_sigma_min_m) and by half a grid spacing per failed
        recovery attempt. With the safety guard, `guard_gate_misses` failures in a row (off-map answers
        aside) also make a zero-velocity update since the last fix suspect (`SafetyGuard.distrust_zupt`), and
        innovation-gate rejections in a row keep the *reported* accuracy at half their disagreement until a fix is
        accepted, while the gate keeps the filter's own P (a silent outlier stays out), when they agree with each other
        (the corrections z - x they imply within confirm_agree_m plus confirm_agree_per_m of the distance driven
        between them, as held answers): the camera then keeps saying the estimate is elsewhere. Rejected answers
        that scatter are the matcher's chance peaks (a 3-D street), not evidence against the estimate.
        innov: the rejected answer's z - x (ENU m), for that comparison; None for one too weak to count
        (plus.guard_w_min), which breaks the run."""
        was_lost = self.lock.state is LockState.LOST
        self.last_answer_weak = reason in ("weak", "at_chance")  # nothing placed: worth asking again soon
        if reason != "no_results":
            self.misses_in_row += 1
        counts = reason == "innovation_gate" and innov is not None
        self._gate_misses = self._gate_misses + 1 if counts else 0
        if counts:
            self._gate_innovs = (self._gate_innovs + [(np.array(innov, dtype=float), odo)])[-self.q.guard_gate_misses:]
        else:
            self._gate_innovs = []
        if self.lock.on_failure(self.timeline.t, reason):
            self.inflate(0.5 * innovation_m)
        elif was_lost:
            self.timeline.widen(0.5 * self.q.grid_spacing_m)
        elif self.q.guard and self._gate_misses >= self.q.guard_gate_misses and self._gate_misses_agree():
            self.report_floor_m = max(self.report_floor_m, 0.5 * innovation_m)
            self.lock.note(self.timeline.t, "fixes_disagree", f"{self._gate_misses} fixes in a row {innovation_m:.1f} m "
                           "away: accuracy widened")
        if self.q.guard and self.misses_in_row >= self.q.guard_gate_misses:
            self.guard.distrust_zupt()

    def _disagreement(self, innov_a: np.ndarray, odo_a: float, innov_b: np.ndarray, odo_b: float) -> float:
        """How far two answers' corrections z - x (ENU m) differ beyond what the IMU may drift between them
        (confirm_agree_per_m of the distance driven, odometer readings odo_a / odo_b m); they agree when this is
        at most confirm_agree_m (held answers, `hold`; rejected ones, `_gate_misses_agree`)."""
        return float(np.linalg.norm(innov_a - innov_b)) - self.q.confirm_agree_per_m * abs(odo_a - odo_b)

    def _gate_misses_agree(self) -> bool:
        """Whether the last guard_gate_misses innovation-gate rejections imply the same correction (`failed`)."""
        kept = self._gate_innovs
        return all(self._disagreement(a[0], a[1], b[0], b[1]) <= self.q.confirm_agree_m
                   for i, a in enumerate(kept) for b in kept[i + 1:])

    def settle_lock(self, state: LockState, jump: float, s_f: float, s_l: float) -> None:
        """Lock bookkeeping after an applied fix. A relocalisation (from LOST) keeps half its jump as a
        1-sigma floor on the position uncertainty until `confirm_fixes` later fixes agree with it to within
        3 fix sigmas; a confirming fix that disagrees restarts the count and keeps the larger floor."""
        if state is LockState.LOST:
            self.lock.on_relocalised(self.timeline.t, jump)
            self._floor_m = 0.5 * jump
            self.report_factor.reset()  # what the fixes said of the old lock says nothing of the new one
        elif state is LockState.CONFIRMING:
            if jump <= 3.0 * max(s_f, s_l):
                self.lock.on_accepted(self.timeline.t)
            else:
                self.lock.confirmations = 0
                self._floor_m = max(self._floor_m, 0.5 * jump)
        else:
            self.lock.on_accepted(self.timeline.t)
        if self.lock.state is LockState.LOCKED:
            self._floor_m = 0.0
        elif self._floor_m > 0.0:
            x, P = self.timeline.ukf.get_state()
            lo = float(np.linalg.eigvalsh(P[:2, :2]).min())
            if lo < self._floor_m**2:
                P[:2, :2] += (self._floor_m**2 - lo) * np.eye(2)
                self.timeline.ukf.set_state(x, P)
