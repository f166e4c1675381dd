"""The paper's method (TACO, Sec. III) as the Localiser's estimator (`make_paper`): the error model's composite
error sets the process noise (`PaperFilter`, Sec. III-F); the dual trigger with its forward-biased cross search
(`PaperTrigger`, Sec. III-D); an answer's best candidate is taken behind the yaw gate (`BestCandidate`, Sec.
III-E) with the w -> sigma mapping (Sec. III-F); a real GNSS reading re-anchors the filter (`ReAnchor`: position
:= the reading). Nothing here goes beyond the paper; taco+ is plus/.

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from taco_mav.core.answer_check import credible, supported
from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.estimator import EstimatorParts, Plan
from taco_mav.core.frames import FixOutcome, FixReason, GnssMeasurement, Tick
from taco_mav.core.gate import passes_yaw_gate, yaw_residual
from taco_mav.core.params import LocaliserParams
from taco_mav.core.queries import Answering, QueryDesk
from taco_mav.core.search import (
    best_candidate,
    cross_offsets,
    cross_spacing,
    fix_position,
    forward_bias,
    trigger_reason,
)
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import FixQuery, MatchResult
from taco_mav.core.ukf import PlanarUkf, process_noise, process_sigmas, weight_sigmas

_NO_MATCH = MatchResult(np.eye(2), np.zeros(2), -1.0)  # a placeholder that never wins best_candidate


def make_paper(timeline: Timeline, desk: QueryDesk, params: LocaliserParams) -> EstimatorParts:
    """The paper's estimator on the Localiser's `timeline` and `desk`."""
    return EstimatorParts(PaperFilter(params, timeline.frame_dt), PaperTrigger(timeline, desk, params),
                     BestCandidate(timeline, desk, params), ReAnchor(timeline, params), report=None, aids=None)


class PaperFilter:
    """(x, y, theta) with the paper's process noise (Sec. III-F); frame_dt: the filter's frame period, s."""

    def __init__(self, params: LocaliserParams, frame_dt: float) -> None:
        self.p, self.frame_dt = params, frame_dt

    def make_ukf(self, x: float, y: float, heading: float) -> PlanarUkf:
        """(x, y, theta) with the paper's initial sigmas (ukf.initial_sigma_xy_m, initial_sigma_theta_rad)."""
        u = self.p.ukf
        s_xy, s_th = u.initial_sigma_xy_m, u.initial_sigma_theta_rad
        return PlanarUkf(np.array([x, y, heading]), np.diag([s_xy**2, s_xy**2, s_th**2]), u.alpha, u.beta, u.kappa)

    # ------------------------------------------------------------------ frames
    def _process_sigmas(self, epsilon: float) -> tuple[float, float]:
        """The paper's per-frame process noise (sigma_fwd, sigma_lat), metres, for the composite error epsilon (m,
        Sec. III-F)."""
        u = self.p.ukf
        return process_sigmas(epsilon, u.sigma_fwd_min_m, u.sigma_fwd_k, u.sigma_lat_min_m, u.sigma_lat_k)

    def predict(self, ukf: PlanarUkf, tick: Tick, terms: ErrorTerms) -> None:
        """UKF predict over one frame with the paper's process noise (Sec. III-F)."""
        inc = tick.inc
        s_f, s_l = self._process_sigmas(terms.epsilon)
        Q = process_noise(float(ukf.x[2]), s_f, s_l, self.p.ukf.sigma_theta_rad, max(inc.dt, 1e-6), self.frame_dt)
        ukf.predict(inc.d_fwd, inc.d_left, inc.d_theta, Q)

    def odometry_sigma(self, tick: Tick) -> float:
        """1/2 (sigma_fwd + sigma_lat) of the paper's process noise (Sec. III-G uses the filter's own noise)."""
        s_f, s_l = self._process_sigmas(tick.terms.epsilon)
        return 0.5 * (s_f + s_l)



class PaperTrigger:
    """The paper's dual trigger (Sec. III-D) on the error model's terms and the time since the last answer."""

    def __init__(self, timeline: Timeline, desk: QueryDesk, params: LocaliserParams) -> None:
        self.timeline, self.desk, self.p = timeline, desk, params

    def plan(self) -> Plan | None:
        """The paper's dual trigger and search (Sec. III-D)."""
        tl, tr = self.timeline, self.p.trigger
        eps = tl.terms.epsilon
        reason = trigger_reason(eps, tl.t - self.desk.answered_t, tr.epsilon_m, tr.time_s)
        if reason is None:
            return None
        bias = forward_bias(eps, tr.forward_bias_k, tr.forward_bias_cap_m) if tr.forward_bias else 0.0
        return reason.value, bias, cross_offsets(cross_spacing(eps, tr.cross_k, tr.cross_cap_m), tr.multi_crop)



class BestCandidate:
    """The best candidate (argmax w, Sec. III-E) behind the yaw gate, with the w -> sigma mapping (Sec. III-F);
    with the answer check on (profile `answer:`), only a credible and supported one."""

    def __init__(self, timeline: Timeline, desk: QueryDesk, params: LocaliserParams) -> None:
        self.timeline, self.desk, self.p = timeline, desk, params

    def judge(self, answer: Answering, results: Sequence[MatchResult | None]) -> FixOutcome:
        """The answer's best candidate fused at its capture frame, or the reason it is not."""
        q, now = answer.query, answer.now
        a = self.p.answer
        checked = a.decoys > 0 or a.w_min > 0.0 or a.min_agree_share > 0.0  # off under the paper's defaults
        raw = results
        if checked:  # the answer check (answer_check.py)
            ok = credible(results, a)
            results = [r if good else None for r, good in zip(results, ok)]
        k = best_candidate([r if r is not None else _NO_MATCH for r in results])
        if checked and not (ok[k] and self._supported(q, raw, ok, k)):
            self.desk.answered(q, now)
            return answer.refused(FixReason.AT_CHANCE)
        best = results[k]
        assert best is not None
        xy = fix_position(q.crop_centres[k], q.heading, best.t, self.p.camera_lever_fwd_left_m)
        psi = yaw_residual(best.R)
        if not (np.all(np.isfinite(xy)) and math.isfinite(psi) and math.isfinite(best.w) and best.w > 0):
            return answer.refused(FixReason.NONFINITE, chosen=k)
        self.desk.answered(q, now)
        if self.p.gate.enabled and not passes_yaw_gate(best.R, self.p.gate.yaw_residual_max_rad):
            return answer.refused(FixReason.YAW_GATE, chosen=k, xy=xy, yaw_residual=psi)
        s_f, s_l = weight_sigmas(self.p.ukf, best.w)
        tick = self.timeline.capture_tick(q.capture_t)
        if tick is None and not self.p.latency.apply_on_arrival:
            return answer.refused(FixReason.STALE, chosen=k, xy=xy, yaw_residual=psi)
        nis = self.timeline.fix(tick, xy, s_f, s_l)
        return answer.accepted(chosen=k, xy=xy, yaw_residual=psi, sigma_fwd=s_f, sigma_lat=s_l, nis=nis)

    def _supported(self, q: FixQuery, results: Sequence[MatchResult | None], ok: np.ndarray, k: int) -> bool:
        """Whether the answer check's agreement holds for the chosen crop k (results: every crop's answer; ok: the
        credible ones)."""
        xy = np.array([fix_position(q.crop_centres[i], q.heading, r.t, self.p.camera_lever_fwd_left_m)
                       if r is not None else (np.nan, np.nan) for i, r in enumerate(results)])
        return supported(xy, k, q.crop_centres, self.p.answer)



class ReAnchor:
    """A real GNSS reading re-anchors the filter: position := the reading; its speed the preintegrator's."""

    replaces = True

    def __init__(self, timeline: Timeline, params: LocaliserParams) -> None:
        self.timeline, self.p = timeline, params

    def apply(self, ukf: PlanarUkf, tick: Tick, m: GnssMeasurement) -> None:
        """The reading re-anchors the filter at `tick`: position := the reading, position covariance :=
        sigma_h^2 I (uncorrelated with the heading)."""
        x, P = ukf.get_state()
        x[:2] = m.xy
        P[:2, :] = 0.0
        P[:, :2] = 0.0
        P[:2, :2] = m.var_xy * np.eye(2)
        ukf.set_state(x, P)

    def fused(self, tick: Tick, m: GnssMeasurement) -> None:
        """After a batch, the newest reading's speed re-anchors the preintegrator's: the speed error at its frame
        less what later re-anchorings set already, kept as `dv_fed` on the latest frame."""
        if m.speed is None:
            return
        tl = self.timeline
        since = sum(h.dv_fed for h in tl.history if h.t > tick.t)  # set after that frame already
        new = tl.pre.speed + m.speed - (tick.inc.speed_end + tick.dv_fed) - since
        if not self.p.imu.allow_reverse:
            new = max(new, 0.0)
        tl.history[-1].dv_fed += new - tl.pre.speed
        tl.pre.speed = new

    def anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        """No bias states: the speed is the receiver's (sigma: the last reading's speed accuracy), the
        accelerometer bias unknown (`Anchor.bias_estimated`). The preintegrator's speed is kept after a rollback:
        without a bias state, integrating the accelerometer from the rewound frame drifts more than a receiver's
        speed a few seconds old."""
        m = next((m for m in reversed(tick.gnss) if m.speed is not None), None)
        sv = math.sqrt(m.var_speed) if m is not None else self.p.gnss.sigma_v_min_mps
        return float(tick.inc.speed_end + tick.dv_fed), 0.0, 0.0, (sv, 0.0, 0.0)
