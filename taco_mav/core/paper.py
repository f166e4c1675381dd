"""The paper's method (TACO, Sec. III) as the Localiser's mode: the error model's composite error sets the process
noise (Sec. III-F) and the dual trigger with its forward-biased cross search (Sec. III-D); an answer's best
candidate is taken behind the yaw gate (Sec. III-E) with the w -> sigma mapping (Sec. III-F); a real GNSS
reading re-anchors the filter (position := the reading). Nothing here goes beyond the paper; taco+ is plus/.

World frame ENU metres, headings ENU radians, times autopilot seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from taco_mav.core.answer_check import credible, supported
from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.frames import FixOutcome, GnssMeasurement, Tick
from taco_mav.core.gate import passes_yaw_gate, yaw_residual
from taco_mav.core.host import Host
from taco_mav.core.search import (
    best_candidate,
    cross_offsets,
    cross_spacing,
    fix_position,
    forward_bias,
    trigger_reason,
)
from taco_mav.core.types import Estimate, FixQuery, GnssFix, GnssOutcome, ImuSample, MatchResult
from taco_mav.core.ukf import PlanarUkf, process_noise, process_sigmas

_NO_MATCH = MatchResult(np.eye(2), np.zeros(2), -1.0)  # a placeholder that never wins best_candidate


class PaperMode:
    """The paper's hooks for the Localiser `host` (see mode.Mode)."""

    takes_ground_motion = False
    gnss_replaces = True

    def __init__(self, host: Host) -> None:
        self.host = host
        self.p = host.p

    def make_ukf(self, x: float, y: float, heading: float) -> PlanarUkf:
        """(x, y, theta) with the paper's initial sigmas (ukf.initial_sigma_xy_m, initial_sigma_theta_rad)."""
        u = self.p.ukf
        s_xy, s_th = u.initial_sigma_xy_m, u.initial_sigma_theta_rad
        return PlanarUkf(np.array([x, y, heading]), np.diag([s_xy**2, s_xy**2, s_th**2]), u.alpha, u.beta, u.kappa)

    # ------------------------------------------------------------------ frames
    def before_imu(self, fresh: bool) -> None:
        pass

    def after_imu(self, sample: ImuSample) -> None:
        pass

    def open_tick(self, tick: Tick) -> None:
        pass

    def after_heading(self, tick: Tick) -> None:
        pass

    def close_tick(self, tick: Tick) -> None:
        pass

    def _process_sigmas(self, epsilon: float) -> tuple[float, float]:
        """The paper's per-frame process noise (sigma_fwd, sigma_lat), metres, for the composite error epsilon (m,
        Sec. III-F)."""
        u = self.p.ukf
        return process_sigmas(epsilon, u.sigma_fwd_min_m, u.sigma_fwd_k, u.sigma_lat_min_m, u.sigma_lat_k)

    def predict(self, tick: Tick, terms: ErrorTerms) -> None:
        """UKF predict over one frame with the paper's process noise (Sec. III-F)."""
        inc, ukf = tick.inc, self.host.ukf
        s_f, s_l = self._process_sigmas(terms.epsilon)
        Q = process_noise(float(ukf.x[2]), s_f, s_l, self.p.ukf.sigma_theta_rad, max(inc.dt, 1e-6), self.host.frame_dt)
        ukf.predict(inc.d_fwd, inc.d_left, inc.d_theta, Q)

    def odometry_sigma(self, tick: Tick) -> float:
        """1/2 (sigma_fwd + sigma_lat) of the paper's process noise (Sec. III-G uses the filter's own noise)."""
        s_f, s_l = self._process_sigmas(tick.terms.epsilon)
        return 0.5 * (s_f + s_l)

    # ------------------------------------------------------------------ trigger and answers
    def plan_search(self) -> tuple[str, float, np.ndarray] | None:
        """The paper's dual trigger and search (Sec. III-D)."""
        host, tr = self.host, self.p.trigger
        eps = host.terms.epsilon
        reason = trigger_reason(eps, host.t - host.last_fix_t, tr.epsilon_m, tr.time_s)
        if reason is None:
            return None
        bias = forward_bias(eps, tr.forward_bias_k, tr.forward_bias_cap_m) if tr.forward_bias else 0.0
        return reason.value, bias, cross_offsets(cross_spacing(eps, tr.cross_k, tr.cross_cap_m), tr.multi_crop)

    def add_fix(self, query_id: int, results: Sequence[MatchResult | None]) -> FixOutcome:
        """The best candidate (argmax w, Sec. III-E) behind the yaw gate, with the w -> sigma mapping."""
        host = self.host
        q = host.take_pending(query_id, results)
        if isinstance(q, FixOutcome):
            return q
        now = host.t
        weights = tuple(float(r.w) if r is not None else 0.0 for r in results)
        a = self.p.answer
        checked = a.decoys > 0 or a.w_min > 0.0 or a.min_agree_share > 0.0  # off under the paper's defaults
        raw = results
        if checked:  # the answer check (answer_check.py)
            ok = credible(results, a)
            results = [r if good else None for r, good in zip(results, ok)]
        k = best_candidate([r if r is not None else _NO_MATCH for r in results])
        if checked and not (ok[k] and self._supported(q, raw, ok, k)):
            host.last_fix_t = max(host.last_fix_t, now if self.p.latency.apply_on_arrival else q.capture_t)
            return host.log(FixOutcome(query_id, False, "at_chance", q.capture_t, now, weights=weights))
        best = results[k]
        assert best is not None
        xy = fix_position(q.crop_centres[k], q.heading, best.t, self.p.camera_lever_fwd_left_m)
        psi = yaw_residual(best.R)
        if not (np.all(np.isfinite(xy)) and math.isfinite(psi) and math.isfinite(best.w) and best.w > 0):
            return host.log(FixOutcome(query_id, False, "nonfinite", q.capture_t, now, k, weights=weights))
        naive = self.p.latency.apply_on_arrival
        host.last_fix_t = max(host.last_fix_t, now if naive else q.capture_t)
        if self.p.gate.enabled and not passes_yaw_gate(best.R, self.p.gate.yaw_residual_max_rad):
            return host.log(FixOutcome(query_id, False, "yaw_gate", q.capture_t, now, k, xy, psi, weights=weights))
        s_f, s_l = host.fix_sigmas(best.w)
        tick = host.capture_tick(q)
        if tick is None and not naive:
            return host.log(FixOutcome(query_id, False, "stale", q.capture_t, now, k, xy, psi, weights=weights))
        nis = host.fuse(tick, xy, s_f, s_l)
        return host.log(FixOutcome(query_id, True, "accepted", q.capture_t, now, k, xy, psi, s_f, s_l, nis, weights))

    def _supported(self, q: FixQuery, results: Sequence[MatchResult | None], ok: np.ndarray, k: int) -> bool:
        """Whether the answer check's agreement holds for the chosen crop k (results: every crop's answer; ok: the
        credible ones)."""
        xy = np.array([fix_position(q.crop_centres[i], q.heading, r.t, self.p.camera_lever_fwd_left_m)
                       if r is not None else (np.nan, np.nan) for i, r in enumerate(results)])
        return supported(xy, k, q.crop_centres, self.p.answer)

    def estimate(self, est: Estimate) -> Estimate:
        """The filter's own estimate, as it is."""
        return est

    # ------------------------------------------------------------------ other inputs: none in the paper
    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        return "ignored"

    def set_drive_command(self, t: float, driving: bool) -> None:
        pass

    def after_gnss(self, fix: GnssFix, out: GnssOutcome) -> None:
        pass

    def lock_events(self) -> list[tuple[float, str, str]]:
        return []

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        return []

    # ------------------------------------------------------------------ a real GNSS: re-anchoring
    def gnss_apply(self, tick: Tick, m: GnssMeasurement) -> None:
        """The reading re-anchors the filter at `tick`: position := the reading, position covariance :=
        sigma_h^2 I (uncorrelated with the heading)."""
        ukf = self.host.ukf
        x, P = ukf.get_state()
        x[:2] = m.xy
        P[:2, :] = 0.0
        P[:, :2] = 0.0
        P[:2, :2] = m.var_xy * np.eye(2)
        ukf.set_state(x, P)

    def gnss_fused_live(self, tick: Tick, m: GnssMeasurement) -> None:
        """After a batch, the newest reading's speed re-anchors the preintegrator's: the speed error at its frame
        less what later re-anchorings set already, kept as `dv_fed` on the latest frame."""
        if m.speed is None:
            return
        host = self.host
        since = sum(h.dv_fed for h in host.history if h.t > tick.t)  # set after that frame already
        new = host.pre.speed + m.speed - (tick.inc.speed_end + tick.dv_fed) - since
        if not self.p.imu.allow_reverse:
            new = max(new, 0.0)
        host.history[-1].dv_fed += new - host.pre.speed
        host.pre.speed = new

    def gnss_anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        """No bias states: the speed is the receiver's (sigma: the last reading's speed accuracy), the
        accelerometer bias unknown (`Anchor.bias_estimated`)."""
        m = next((m for m in reversed(tick.gnss) if m.speed is not None), None)
        sv = math.sqrt(m.var_speed) if m is not None else self.p.gnss.sigma_v_min_mps
        return float(tick.inc.speed_end + tick.dv_fed), 0.0, 0.0, (sv, 0.0, 0.0)

    def gnss_after_rollback(self) -> None:
        """The preintegrator's speed is kept: without a bias state, integrating the accelerometer from the
        rewound frame drifts more than a receiver's speed a few seconds old."""
