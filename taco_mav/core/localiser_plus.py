"""taco+ (issue 7): the Localiser with the paper's heuristics replaced where they lose lock or overwrite the
state (see `plus.py` for the pieces, `lock.py` for loss-of-lock recovery, and the mixins: `answer_hold.py` held
answers and failures, `safety_guard.py`, `camera_speed.py`, `gnss_plus.py` a real GNSS). Same facade, same
history replay for late fixes; paper mode (`Localiser`) is untouched.

State: x, y (ENU m), theta (ENU rad), dv (speed error, m/s), b (forward accelerometer bias, m/s^2). After every
frame the speed error is moved into the preintegrator (error-state feedback), so `estimate().speed` is the
corrected speed; the amount is kept on the frame so a replay after a late fix subtracts it again.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from taco_mav.core.answer_hold import AnswerHoldMixin
from taco_mav.core.camera_speed import CameraSpeedMixin
from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.gate import yaw_residual
from taco_mav.core.gnss_plus import GnssPlusMixin
from taco_mav.core.imu_check import UnaidedTrack
from taco_mav.core.frames import FixOutcome, Tick
from taco_mav.core.localiser import Localiser
from taco_mav.core.lock import LockMonitor, LockState
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus import (FixNoiseScale, VarianceFactor, bias_decay, consensus, cross_arm, defer_answer,
                                grid_rings, hex_offsets, n_states, process_noise_plus)
from taco_mav.core.safety_guard import SafetyGuardMixin
from taco_mav.core.search import cross_offsets, fix_position
from taco_mav.core.speed_check import SpeedCheck
from taco_mav.core.stationary import StationaryDetector
from taco_mav.core.types import Estimate, ImuSample, MatchResult, horizontal_sigma
from taco_mav.core.ukf import PlanarUkf, fix_covariance


def make_localiser(params: LocaliserParams, t0: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0,
                   speed: float = 0.0, record: bool = True, heading_offset: float = 0.0) -> Localiser:
    """The Localiser for the estimator mode in `params`: paper (params.plus is None) or taco+."""
    cls = Localiser if params.plus is None else PlusLocaliser
    return cls(params, t0, x, y, heading, speed, record=record, heading_offset=heading_offset)


class PlusLocaliser(CameraSpeedMixin, SafetyGuardMixin, AnswerHoldMixin, GnssPlusMixin, Localiser):
    """taco+ mode. Construct through `make_localiser` (or directly with params.plus set)."""

    takes_ground_motion = True

    def __init__(self, params: LocaliserParams, t0: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0,
                 speed: float = 0.0, record: bool = True, heading_offset: float = 0.0) -> None:
        if params.plus is None:
            raise ValueError("PlusLocaliser needs params.plus (the taco+ parameters)")
        self.q = params.plus
        super().__init__(params, t0, x, y, heading, speed, record, heading_offset)
        self.pre.gyro_heading = self.q.gyro_heading
        q, s_xy, s_th = self.q, params.ukf.initial_sigma_xy_m, params.ukf.initial_sigma_theta_rad
        var = [s_xy**2, s_xy**2, s_th**2, q.initial_speed_sigma_mps**2, q.initial_bias_sigma_mps2**2,
               q.compass_bias_sigma_rad**2][:n_states(q)]
        g = params.map_georef_sigma_m  # the map's georeferencing offset as two more states (ukf.py)
        if g > 0.0:
            if len(var) != 6:
                raise ValueError("map.georef_sigma_m > 0 needs the compass-bias state (plus.compass_bias_sigma_rad > 0)")
            var += [g * g, g * g]
        self.ukf = PlanarUkf(np.array([x, y, heading] + [0.0] * (len(var) - 3)), np.diag(var), params.ukf.alpha,
                             params.ukf.beta, params.ukf.kappa)
        self.still = StationaryDetector(q.zupt_window_s, q.zupt_gyro_max_rps, q.zupt_accel_std_max_mps2,
                                        q.zupt_accel_mean_max_mps2)
        self.unaided = UnaidedTrack(q.guard_k, q.guard_floor_m, q.imu_accel_sigma_mps2)
        self._queries = 0  # queries planned since the start
        self._guard_added = 0.0  # position variance the guard added since the last accepted fix, m^2
        self._guard_flagged = False
        self._zupt_holdoff_until = -math.inf
        self._gate_misses = 0  # consecutive innovation-gate rejections (of at least plus.guard_w_min)
        self._gate_innovs: list[tuple[np.ndarray, float]] = []  # ... their z - x (ENU m) and odometer (m)
        self._misses_in_row = 0  # consecutive answered triggers without a fix (off-map answers aside)
        self._last_answer_weak = False  # the last answer had nothing usable (plus.trigger_retry_s asks sooner)
        self._report_floor_m = 0.0  # 1-sigma floor on the reported (not the filter's) position accuracy, m
        self._zupt_since_reset = False  # a zero-velocity update since the IMU-only track was reset
        self._speed_seen_t, self._speed_seen_sigma = t0, q.initial_speed_sigma_mps  # last speed observation
        self._drive: tuple[float, bool] | None = None  # (t, the autopilot drives) from set_drive_command
        self._camera_moving_until = -math.inf  # the camera saw the ground move: no zero-velocity update
        self._camera_gated = 0  # camera speed measurements held off in a row
        self._camera_suspect, self._camera_agree = False, 0  # camera locked onto something else (camera_speed.py)
        self._gnss_was_healthy = False  # the real GNSS was in use at the last trigger check
        self.speed_check = SpeedCheck()  # GNSS ground speed against the camera's (spoofing, speed_check.py)
        self.lock = LockMonitor(q.lost_after, q.lost_after_s, q.capture_radius_m, q.confirm_fixes, last_accept_t=t0)
        self._last_answer_t = -math.inf
        self._zupt = False  # the last frame had a zero-velocity update
        self._floor_m = 0.0  # relocalisation jump kept in P until confirmed, metres (1-sigma)
        self.fix_scale = FixNoiseScale(q.fix_scale_min, q.fix_scale_max, q.fix_scale_window,
                                       s2=min(max(q.fix_scale_initial, q.fix_scale_min), q.fix_scale_max) ** 2)
        self.report_factor = VarianceFactor(q.report_factor_min, q.report_factor_max, q.report_window)
        self._odo = 0.0  # distance travelled, metres (new frames only)
        self._track_unit = (0.0, 0.0)  # integral of the compass's unit heading vector over time, s (ENU)
        self._odo_at_query = 0.0  # ... when the last query was planned
        self._odo_at_fix = 0.0  # ... at the capture of the last accepted fix
        self._deferred = 0  # weak answers deferred in a row (defer_w)
        # held answers (jump_confirm_k, recover_confirm), newest last: (the correction z - x at capture (ENU m),
        # arrival t of the latest agreeing answer, odometer then, answers that agreed so far, the integral of the
        # unit heading vector at capture (s, ENU; confirm_speed_error_mps))
        self._held: list[tuple[np.ndarray, float, float, int, tuple[float, float] | None]] = []

    # ------------------------------------------------------------------ IMU path
    def add_imu(self, sample: ImuSample) -> None:
        fresh = sample.t > self.pre.t
        if fresh and self.q.guard and not self.unaided.started:
            self._reset_unaided()
        super().add_imu(sample)
        if fresh:
            self.still.add(sample.t, sample.accel_frd, sample.gyro_frd, self.pre.accel_fwd)
            if self.q.guard:
                self.unaided.add(sample.t, self.pre.accel_fwd, self.pre.theta, self.p.imu.allow_reverse)

    def set_drive_command(self, t: float, driving: bool) -> None:
        """What the autopilot commands at time t (s): True while it drives (armed with a throttle output), False
        while it does not. A driving autopilot vetoes zero-velocity updates (for drive_command_timeout_s)."""
        self._drive = (t, driving)

    def _driving(self) -> bool:
        """The autopilot drives (a recent drive command), or the camera saw the ground move."""
        d = self._drive
        return (d is not None and d[1] and self.t - d[0] <= self.q.drive_command_timeout_s
                or self.t <= self._camera_moving_until)

    def _open_tick(self, tick: Tick) -> None:
        inc = tick.inc  # what a speed error of 1 m/s moves the estimate by over this frame, ENU metres
        mid = tick.theta_start + 0.5 * inc.d_theta
        ux, uy = self._track_unit
        self._track_unit = tick.track_unit = (ux + inc.dt * math.cos(mid), uy + inc.dt * math.sin(mid))
        # The IMU alone cannot tell a smooth cruise from a stop: also require a speed the filter cannot tell from
        # zero. The speed the IMU may have lost since the speed was last observed (a fix, a stop) is what its
        # accelerometer error integrates to, not the filter's speed random walk (issue 19: with q_speed 0.5 a
        # smooth 3 m/s cruise fell inside 3 sigma within seconds and the ZUPT pinned it to zero). Never while
        # the autopilot drives, nor while the safety guard holds zero-velocity updates off.
        q = self.q
        tau = max(self.t - self._speed_seen_t, 0.0)
        drift = (math.sqrt(max(float(self.ukf.P[4, 4]), 0.0)) + q.imu_accel_sigma_mps2) * tau
        gate = q.zupt_speed_max_mps + 3.0 * (self._speed_seen_sigma + drift)
        bias = float(self.ukf.x[4])
        tick.stationary = bool(q.zupt and abs(self.pre.speed) <= gate and self.t >= self._zupt_holdoff_until
                               and not self._driving() and self.still.still(bias))
        if tick.stationary:
            self._speed_seen(q.zupt_sigma_mps)
            self._zupt_since_reset = True
        self._zupt = tick.stationary

    def _speed_seen(self, sigma_mps: float) -> None:
        """The speed was just observed (a stop, a fix) with this 1-sigma, m/s."""
        self._speed_seen_t, self._speed_seen_sigma = self.t, sigma_mps

    def _predict(self, tick: Tick, terms: ErrorTerms) -> None:
        inc = tick.inc
        dt = max(inc.dt, 1e-6)
        Q = process_noise_plus(float(self.ukf.x[2]), dt, inc.distance, self.q, n=len(self.ukf.x))
        self.ukf.predict(inc.d_fwd, inc.d_left, inc.d_theta, Q, dt=inc.dt, bias_decay=bias_decay(dt, self.q))

    def _odometry_sigma(self, tick: Tick) -> float:
        """The smoother's odometry sigma for this frame, metres: taco+'s own position process noise plus what
        the speed-error uncertainty moves the frame by (sigma_dv dt), instead of the paper's >= 1 m."""
        inc = tick.inc
        Q = process_noise_plus(float(tick.x[2]), max(inc.dt, 1e-6), inc.distance, self.q)
        return max(math.sqrt(0.5 * float(np.trace(Q[:2, :2]))) + math.sqrt(max(float(tick.P[3, 3]), 0.0)) * inc.dt,
                   1e-3)

    def _after_heading(self, tick: Tick) -> None:
        if tick.stationary:  # true speed 0: dv = -(preintegrated speed at the frame end)
            self.ukf.update_speed_error(-tick.inc.speed_end, self.q.zupt_sigma_mps)
        if tick.dv_fed:
            self.ukf.x[3] -= tick.dv_fed

    def _close_tick(self, tick: Tick) -> None:
        self._odo += tick.inc.distance
        self._feedback(tick)
        if self.q.gyro_heading:  # the gyro integrates on from the filter's heading
            self.pre.rebase_heading(float(self.ukf.x[2]))
        if self.q.guard:
            self._guard()

    def _feedback(self, tick: Tick) -> None:
        """Move the speed-error estimate into the preintegrator (clamped at 0 unless reversing is allowed)."""
        old = self.pre.speed
        new = old + float(self.ukf.x[3])
        if not self.p.imu.allow_reverse:
            new = max(new, 0.0)
        applied = new - old
        if applied:
            self.pre.speed = new
            self.ukf.x[3] -= applied
            tick.dv_fed += applied
            tick.x[3] -= applied

    # ------------------------------------------------------------------ trigger and search
    def _plan_search(self) -> tuple[str, float, np.ndarray] | None:
        q = self.q
        sig = horizontal_sigma(self.ukf.P)
        if self.lock.on_uncertainty(self.t, sig):
            self._inflate(sig)
            sig = horizontal_sigma(self.ukf.P)
        if self.t - self._last_answer_t < q.recover_interval_s:
            return None
        state = self.lock.state
        if state is LockState.LOST:
            rings = min(grid_rings(sig, q) + self.lock.attempts, q.grid_max_rings)
            return self._planned("recover", hex_offsets(rings, q.grid_spacing_m))
        arm = cross_offsets(cross_arm(sig, q), self.p.trigger.multi_crop)
        if any(self.t - h[1] <= q.confirm_window_s for h in self._held):
            return self._planned("verify", arm)  # a held answer waits for a second one
        if state is LockState.CONFIRMING:
            return self._planned("confirm", arm)
        if self._gnss_handover():
            return self._planned("handover", arm)
        if self._map_anchored(sig):
            return self._planned("map", arm)
        retry = q.defer_retry_m if self._deferred else q.trigger_retry_m
        if (q.trigger_distance_m > 0.0 and self._odo - self._odo_at_fix >= q.trigger_distance_m
                and self._odo - self._odo_at_query >= retry):
            return self._planned("distance", arm)
        if sig >= q.trigger_sigma_m:
            return self._planned("covariance", arm)
        # also at an apparent stop (one the IMU cannot tell from a smooth cruise must not silence the camera,
        # issue 19), unless the autopilot confirms it does not drive
        d = self._drive
        stopped = d is not None and not d[1] and self.t - d[0] <= q.drive_command_timeout_s
        every = q.trigger_retry_s if q.trigger_retry_s > 0.0 and self._last_answer_weak else q.trigger_time_s
        if self.t - self._last_fix_t >= every and not (stopped and (self._zupt or self.still.stationary)):
            return self._planned("time", arm)
        return None

    def _planned(self, reason: str, offsets: np.ndarray) -> tuple[str, float, np.ndarray]:
        self._odo_at_query = self._odo
        self._queries += 1
        return reason, 0.0, offsets

    def _map_anchored(self, sig: float) -> bool:
        """The map trigger (config plus.map_trigger_ratio): with the map's offset as states, the position (1-sigma
        `sig`, m) is known better than map_trigger_ratio times the offset's 1-sigma in its least known direction,
        so a fix now teaches the offset; asked at once, then every map_trigger_m metres while it lasts."""
        if len(self.ukf.x) < 8 or self.q.map_trigger_ratio <= 0.0:
            return False
        lam_b = float(np.linalg.eigvalsh(self.ukf.P[6:8, 6:8])[-1])
        if sig * sig >= self.q.map_trigger_ratio**2 * lam_b:
            return False
        return self._queries == 0 or self._odo - self._odo_at_query >= self.q.map_trigger_m

    def _gnss_handover(self) -> bool:
        """True once when the real GNSS that was in use is lost or held off: the camera at once, rather than
        when the uncertainty has grown, takes over from the receiver's wandering position (issue 14)."""
        g = self.gnss_guard
        healthy = g is not None and g.healthy_at(self.t)
        lost = self._gnss_was_healthy and not healthy
        self._gnss_was_healthy = healthy
        return lost

    def _inflate(self, sigma_m: float) -> None:
        """Lock lost: widen the position uncertainty by at least lost_sigma_min_m (and sigma_m), metres."""
        self._widen(max(self.q.lost_sigma_min_m, sigma_m))

    def _widen(self, s: float) -> None:
        """Add s^2 (m^2) to both position variances."""
        x, P = self.ukf.get_state()
        P[:2, :2] += s * s * np.eye(2)
        self.ukf.set_state(x, P)

    # ------------------------------------------------------------------ fixes
    def add_fix(self, query_id: int, results: Sequence[MatchResult | None]) -> FixOutcome:
        """As Localiser.add_fix, with consensus over the candidates, the chi-square innovation gate and the
        lock state machine (every answered trigger without an accepted fix counts towards loss of lock)."""
        q = self._take_pending(query_id, results)
        self._last_answer_t = self.t
        if isinstance(q, FixOutcome):
            if q.reason == "no_results":
                self._failed(q.reason, 0.0)
            return q
        now, p, qp = self.t, self.p, self.q
        weights = tuple(float(r.w) if r is not None else 0.0 for r in results)
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
        usable = finite & yaw_ok & (w >= (qp.recover_w_min if self.lock.state is LockState.LOST else qp.w_min))
        c = consensus(np.nan_to_num(xy), w, usable, qp.consensus_radius_m, qp.consensus_weight_power)
        self._last_fix_t = max(self._last_fix_t, now if p.latency.apply_on_arrival else q.capture_t)
        if c is None:
            reason = "nonfinite" if not finite.any() else ("yaw_gate" if not (finite & yaw_ok).any() else "weak")
            self._failed(reason, 0.0)
            return self._log(FixOutcome(query_id, False, reason, q.capture_t, now, weights=weights))
        k, z = c.index, c.xy
        tick = self._capture_tick(q)
        if tick is None:
            return self._log(FixOutcome(query_id, False, "stale", q.capture_t, now, k, z, psi[k], weights=weights))
        if self._defer(c.weight, tick.P):  # weak, and the filter can wait for a better one: ask again
            return self._log(FixOutcome(query_id, False, "deferred", q.capture_t, now, k, z, psi[k], weights=weights))
        # the matcher's w mapped as in the paper (plus.fix_isotropic: both sigmas their mean)
        s_f0, s_l0 = self._fix_sigmas(c.weight, False if qp.fix_isotropic else None)
        sc = self.fix_scale.scale if qp.adaptive_fix_noise else 1.0  # what earlier fixes taught
        s_f, s_l = sc * s_f0, sc * s_l0
        pred, Pz = self.ukf.fix_prediction(tick.x, tick.P)  # position (+ the map's offset), its covariance
        innov = z - pred
        jump = float(np.linalg.norm(innov))
        nis = float(innov @ np.linalg.solve(Pz + fix_covariance(float(tick.x[2]), s_f, s_l), innov))
        state = self.lock.state
        if state is LockState.LOST:
            gate = qp.recover_chi2_gate if qp.recover_chi2_gate > 0.0 else math.inf  # under the widened P
        else:
            gate = qp.chi2_gate if c.support > 1 else qp.chi2_gate_single
        if nis > gate:
            self._failed("innovation_gate", jump, innov if c.weight >= qp.guard_w_min else None)
            return self._log(FixOutcome(query_id, False, "innovation_gate", q.capture_t, now, k, z, psi[k], s_f, s_l,
                                        nis, weights))
        held = self._hold(state, innov, jump, Pz, now, now - q.capture_t, tick.track_unit)
        if held == "hold":
            self._failed("unconfirmed", jump)
            return self._log(FixOutcome(query_id, False, "unconfirmed", q.capture_t, now, k, z, psi[k], s_f, s_l, nis,
                                        weights))
        if state is LockState.LOST or held == "confirmed":  # relocalise: the candidate replaces the position
            tick.P = tick.P.copy()  # (the jump enters P)
            tick.P[:2, :2] += jump * jump * np.eye(2)
        self._held = []
        learn = state is LockState.LOCKED and held is None
        if qp.adaptive_fix_noise and learn:  # learn from this fix for the next ones
            self.fix_scale.update(innov, Pz, fix_covariance(float(tick.x[2]), s_f0, s_l0))
        # the answer's rotation measures the true heading at capture (plus.fix_yaw_sigma_rad; 0: gate only)
        heading = (q.heading + float(psi[k]), qp.fix_yaw_sigma_rad) if qp.fix_yaw_sigma_rad > 0.0 else None
        self._fuse(tick, z, s_f, s_l, heading)
        self._odo_at_fix = max(self._odo_at_fix, self._odo_at_query)  # the query was planned at its capture
        if learn:
            self.report_factor.update(nis)
        # a confirmed jump is a relocalisation: half of it stays in P until confirm_fixes later fixes agree
        self._settle_lock(LockState.LOST if held == "confirmed" else state, jump, s_f, s_l)
        if self._history:
            self._feedback(self._history[-1])
        self._gate_misses = self._misses_in_row = self._deferred = 0
        self._last_answer_weak = False
        self._gate_innovs = []
        self._report_floor_m = 0.0
        self._speed_seen(math.sqrt(max(float(self.ukf.P[3, 3]), 0.0)))
        if self.q.guard:
            self._reset_unaided()
        return self._log(FixOutcome(query_id, True, "accepted", q.capture_t, now, k, z, psi[k], s_f, s_l, nis, weights))

    def _defer(self, w: float, P: np.ndarray) -> bool:
        """Whether to leave a weak answer (consensus weight w) unused and ask again (plus.defer_answer)."""
        healthy = self.lock.state is LockState.LOCKED and not self._guard_flagged
        if defer_answer(w, self._deferred, healthy, horizontal_sigma(P), self._odo - self._odo_at_fix, self.q):
            self._deferred += 1
            return True
        return False

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> Estimate:
        est = super().estimate()
        x = self.ukf.x
        # The fixes' variance factor makes the reported accuracy honest while locked and while the safety guard
        # agrees; otherwise the filter's own (widened) covariance is reported as it is (issue 18).
        # Not while a real GNSS is fused: the factor is learnt from camera fixes and says nothing of the
        # receiver's wander, which _gnss_apply keeps in P.
        if (self.q.report_calibration and self.lock.state is LockState.LOCKED and not self._guard_flagged
                and not self.gnss_in_use):
            est = dataclasses.replace(est, cov_xy=self.report_factor.factor * est.cov_xy)
        lo = float(np.linalg.eigvalsh(est.cov_xy).min()) if np.all(np.isfinite(est.cov_xy)) else math.inf
        if lo < self._report_floor_m**2:
            est = dataclasses.replace(est, cov_xy=est.cov_xy + (self._report_floor_m**2 - lo) * np.eye(2))
        est.extra.update(lock=self.lock.state.value, speed_error=float(x[3]), accel_bias=float(x[4]),
                         compass_bias=float(x[5]) if len(x) > 5 else 0.0, fix_scale=self.fix_scale.scale,
                         map_offset=[float(v) for v in x[6:8]],
                         stationary=self._zupt)
        return est

    @property
    def lock_events(self) -> list[tuple[float, str, str]]:
        """(t, kind, detail) of lock_lost / relocalised / relock_failed / recovered."""
        return list(self.lock.events)

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """The lock events not yet taken (the daemon logs each once)."""
        return self.lock.take_unreported()
