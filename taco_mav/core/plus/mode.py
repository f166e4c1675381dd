"""taco+ as the Localiser's estimator: the paper's heuristics replaced where they lose lock or overwrite the
state. The pieces are parts this mode owns: the noise model and what the fixes teach (noise.py), the trigger and
search (search.py), the lock state machine (lock.py), held answers and failures (answer_hold.py), stops
(zero_velocity.py), the safety guard (safety_guard.py), the camera's speed (camera_speed.py) and the update by a
real GNSS (gnss.py). The Localiser's timeline keeps the history and replays it for late corrections; paper
mode (`paper.PaperMode`) is untouched.

State: x, y (ENU m), theta (ENU rad), dv (speed error, m/s), b (forward accelerometer bias, m/s^2), optionally
beta (compass bias, rad) and the map's offset (ENU m). After every frame the speed error is moved into the
preintegrator (error-state feedback, `feedback`), so `estimate().speed` is the corrected speed; the amount is
kept on the frame (a `SpeedFeedback` correction) so a replay after a late fix subtracts it again.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from taco_mav.core.answer_check import credible, supported
from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.corrections import SpeedFeedback, ZeroSpeed
from taco_mav.core.frames import FixOutcome, FixReason, GnssMeasurement, Tick
from taco_mav.core.gate import yaw_residual
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.answer_hold import AnswerHold
from taco_mav.core.plus.camera_speed import CameraSpeed
from taco_mav.core.plus.gnss import KalmanGnss
from taco_mav.core.plus.lock import LockMonitor, LockState
from taco_mav.core.plus.noise import (
    FixNoiseScale,
    VarianceFactor,
    bias_decay,
    n_states,
    process_noise_plus,
)
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.search import (
    consensus,
    cross_arm,
    defer_answer,
    grid_rings,
    hex_offsets,
)
from taco_mav.core.plus.speed_scale import ScaleConsider
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.search import cross_offsets, fix_position
from taco_mav.core.types import (
    Estimate,
    GnssFix,
    GnssOutcome,
    ImuSample,
    MatchResult,
    horizontal_sigma,
)
from taco_mav.core.queries import Answering, QueryDesk
from taco_mav.core.timeline import Timeline
from taco_mav.core.ukf import PlanarUkf, fix_covariance, weight_sigmas


class PlusMode:
    """taco+'s estimator (see mode.Estimator) and its aiding (mode.Aids) on the Localiser's `timeline`, `desk`
    and `gnss`, with q the taco+ parameters (params.plus)."""

    gnss_replaces = False  # a Kalman update, not a re-anchoring

    def __init__(self, timeline: Timeline, desk: QueryDesk, gnss: GnssFusion, params: LocaliserParams,
                 q: PlusParams) -> None:
        self.timeline, self.desk, self.gnss_status, self.p, self.q = timeline, desk, gnss, params, q
        self.aids = self
        t0 = timeline.t
        timeline.pre.gyro_heading = q.gyro_heading
        self.lock = LockMonitor(q.lost_after, q.lost_after_s, q.capture_radius_m, q.confirm_fixes, last_accept_t=t0)
        self.fix_scale = FixNoiseScale(q.fix_scale_min, q.fix_scale_max, q.fix_scale_window,
                                       s2=min(max(q.fix_scale_initial, q.fix_scale_min), q.fix_scale_max) ** 2)
        self.report_factor = VarianceFactor(q.report_factor_min, q.report_factor_max, q.report_window)
        self.lock_events = self.lock.events
        self.guard = SafetyGuard(timeline, q, self.lock)
        self.zero = ZeroVelocity(timeline, q, self.guard, t0)
        self.answers = AnswerHold(timeline, q, self.lock, self.report_factor, self.guard)
        self.camera = CameraSpeed(timeline, gnss, q, self.zero, self.guard, self.feedback)
        self.gnss = KalmanGnss(timeline, q, self.zero, self.guard, self.feedback)
        self.scale = ScaleConsider(q.camera_speed_scale_sigma)  # the camera speed's scale error (a consider term)
        self.odo = 0.0  # distance travelled, metres (new frames only)
        self._queries = 0  # queries planned since the start
        self._track_unit = (0.0, 0.0)  # integral of the compass's unit heading vector over time, s (ENU)
        self._odo_at_query = 0.0  # odometer when the last query was planned, m
        self._odo_at_fix = 0.0  # ... at the capture of the last accepted fix
        self._deferred = 0  # weak answers deferred in a row (defer_w)
        self._last_answer_t = -math.inf
        self._gnss_was_healthy = False  # the real GNSS was in use at the last trigger check

    def make_ukf(self, x: float, y: float, heading: float) -> PlanarUkf:
        """(x, y, theta, dv, b[, beta][, the map's offset]) with taco+'s initial sigmas; map.georef_sigma_m > 0
        adds the map's georeferencing offset as two more states (ukf.py)."""
        p, q = self.p, self.q
        s_xy, s_th = p.ukf.initial_sigma_xy_m, p.ukf.initial_sigma_theta_rad
        var = [s_xy**2, s_xy**2, s_th**2, q.initial_speed_sigma_mps**2, q.initial_bias_sigma_mps2**2,
               q.compass_bias_sigma_rad**2][:n_states(q)]
        g = p.map_georef_sigma_m
        if g > 0.0:
            if len(var) != 6:
                raise ValueError("map.georef_sigma_m > 0 needs the compass-bias state "
                                 "(plus.compass_bias_sigma_rad > 0)")
            var += [g * g, g * g]
        return PlanarUkf(np.array([x, y, heading] + [0.0] * (len(var) - 3)), np.diag(var), p.ukf.alpha, p.ukf.beta,
                         p.ukf.kappa)

    # ------------------------------------------------------------------ IMU path and frames
    def before_imu(self) -> None:
        if self.q.guard and not self.guard.unaided.started:
            self.guard.reset()

    def after_imu(self, sample: ImuSample) -> None:
        pre = self.timeline.pre
        self.zero.add_imu(sample, pre.accel_fwd)
        if self.q.guard:
            self.guard.add_imu(sample.t, pre.accel_fwd, pre.theta)

    def set_drive_command(self, t: float, driving: bool) -> None:
        self.zero.set_drive_command(t, driving)

    def open_frame(self, tick: Tick) -> None:
        inc = tick.inc  # what a speed error of 1 m/s moves the estimate by over this frame, ENU metres
        mid = tick.theta_start + 0.5 * inc.d_theta
        ux, uy = self._track_unit
        self._track_unit = tick.track_unit = (ux + inc.dt * math.cos(mid), uy + inc.dt * math.sin(mid))
        self.scale.advance(tick, mid)
        if self.zero.decide():
            tick.add(ZeroSpeed(self.q.zupt_sigma_mps))

    def predict(self, ukf: PlanarUkf, tick: Tick, terms: ErrorTerms) -> None:
        """UKF predict over one frame with taco+'s process noise (noise.py), the compass bias decaying."""
        inc = tick.inc
        dt = max(inc.dt, 1e-6)
        Q = process_noise_plus(float(ukf.x[2]), dt, inc.distance, self.q, n=len(ukf.x))
        ukf.predict(inc.d_fwd, inc.d_left, inc.d_theta, Q, dt=inc.dt, bias_decay=bias_decay(dt, self.q))

    def odometry_sigma(self, tick: Tick) -> float:
        """The smoother's odometry sigma for this frame, metres: taco+'s own position process noise plus what
        the speed-error uncertainty moves the frame by (sigma_dv dt), instead of the paper's >= 1 m."""
        inc = tick.inc
        Q = process_noise_plus(float(tick.x[2]), max(inc.dt, 1e-6), inc.distance, self.q)
        return max(math.sqrt(0.5 * float(np.trace(Q[:2, :2]))) + math.sqrt(max(float(tick.P[3, 3]), 0.0)) * inc.dt,
                   1e-3)

    def close_frame(self, tick: Tick) -> None:
        self.odo += tick.inc.distance
        self.feedback(tick)
        if self.q.gyro_heading:  # the gyro integrates on from the filter's heading
            self.timeline.pre.rebase_heading(float(self.timeline.ukf.x[2]))
        if self.q.guard:
            self.guard.check()

    def feedback(self, tick: Tick) -> None:
        """Move the speed-error estimate into the preintegrator (clamped at 0 unless reversing is allowed)."""
        pre, ukf = self.timeline.pre, self.timeline.ukf
        old = pre.speed
        new = old + float(ukf.x[3])
        if not self.p.imu.allow_reverse:
            new = max(new, 0.0)
        applied = new - old
        if applied:
            pre.speed = new
            ukf.x[3] -= applied
            if not any(isinstance(c, SpeedFeedback) for c in tick.corrections):
                tick.add(SpeedFeedback())
            tick.dv_fed += applied
            tick.x[3] -= applied

    # ------------------------------------------------------------------ trigger and search
    def plan_search(self) -> tuple[str, float, np.ndarray] | None:
        """taco+'s trigger (search.py): recover while lock is lost, verify a held answer, confirm, hand over
        from a lost GNSS, the map trigger, distance, covariance, time."""
        tl, q = self.timeline, self.q
        sig = horizontal_sigma(tl.ukf.P)
        if self.lock.on_uncertainty(tl.t, sig):
            self.answers.inflate(sig)
            sig = horizontal_sigma(tl.ukf.P)
        if tl.t - self._last_answer_t < q.recover_interval_s:
            return None
        state = self.lock.state
        if state is LockState.LOST:
            rings = min(grid_rings(sig, q) + self.lock.attempts, q.grid_max_rings)
            return self._planned("recover", hex_offsets(rings, q.grid_spacing_m))
        arm = cross_offsets(cross_arm(sig, q), self.p.trigger.multi_crop)
        if any(tl.t - h[1] <= q.confirm_window_s for h in self.answers.held):
            return self._planned("verify", arm)  # a held answer waits for a second one
        if state is LockState.CONFIRMING:
            return self._planned("confirm", arm)
        if self._gnss_handover():
            return self._planned("handover", arm)
        if self._map_anchored(sig):
            return self._planned("map", arm)
        retry = q.defer_retry_m if self._deferred else q.trigger_retry_m
        if (q.trigger_distance_m > 0.0 and self.odo - self._odo_at_fix >= q.trigger_distance_m
                and self.odo - self._odo_at_query >= retry):
            return self._planned("distance", arm)
        if sig >= q.trigger_sigma_m:
            return self._planned("covariance", arm)
        # also at an apparent stop (one the IMU cannot tell from a smooth cruise must not silence the camera,
        # issue 19), unless the autopilot confirms it does not drive
        stopped = self.zero.stopped_on_command()
        every = q.trigger_retry_s if q.trigger_retry_s > 0.0 and self.answers.last_answer_weak else q.trigger_time_s
        if tl.t - self.desk.answered_t >= every and not (stopped and (self.zero.active or self.zero.still.stationary)):
            return self._planned("time", arm)
        return None

    def _planned(self, reason: str, offsets: np.ndarray) -> tuple[str, float, np.ndarray]:
        self._odo_at_query = self.odo
        self._queries += 1
        return reason, 0.0, offsets

    def _map_anchored(self, sig: float) -> bool:
        """The map trigger (config plus.map_trigger_ratio): with the map's offset as states, the position (1-sigma
        `sig`, m) is known better than map_trigger_ratio times the offset's 1-sigma in its least known direction,
        so a fix now teaches the offset; asked at once, then every map_trigger_m metres while it lasts."""
        ukf = self.timeline.ukf
        if len(ukf.x) < 8 or self.q.map_trigger_ratio <= 0.0:
            return False
        lam_b = float(np.linalg.eigvalsh(ukf.P[6:8, 6:8])[-1])
        if sig * sig >= self.q.map_trigger_ratio**2 * lam_b:
            return False
        return self._queries == 0 or self.odo - self._odo_at_query >= self.q.map_trigger_m

    def _gnss_handover(self) -> bool:
        """True once when the real GNSS that was in use is lost or held off: the camera at once, rather than
        when the uncertainty has grown, takes over from the receiver's wandering position (issue 14)."""
        g = self.gnss_status.guard
        healthy = g is not None and g.healthy_at(self.timeline.t)
        lost = self._gnss_was_healthy and not healthy
        self._gnss_was_healthy = healthy
        return lost

    # ------------------------------------------------------------------ fixes
    def answer_missing(self, out: FixOutcome) -> None:
        """An answer that answers no query in flight, or holds nothing (`out`): the latter counts towards loss of
        lock."""
        self._last_answer_t = self.timeline.t
        if out.reason is FixReason.NO_RESULTS:
            self.answers.failed(out.reason, 0.0, self.odo)

    def judge(self, answer: Answering, results: Sequence[MatchResult | None]) -> FixOutcome:
        """Consensus over the candidates, the chi-square innovation gate, held answers and the lock state machine
        (every answered trigger without an accepted fix counts towards loss of lock)."""
        tl, answers = self.timeline, self.answers
        q, now, p, qp = answer.query, answer.now, self.p, self.q
        self._last_answer_t = now
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
            answers.failed(reason, 0.0, self.odo)
            return answer.refused(reason)
        k, z = c.index, c.xy
        if lost and not supported(xy, k, q.crop_centres, p.answer):  # one or two crops of five: the crops' own
            answers.failed(FixReason.AT_CHANCE, 0.0, self.odo)
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
        innov = z - pred
        jump = float(np.linalg.norm(innov))
        nis = float(innov @ np.linalg.solve(Pz + fix_covariance(float(tick.x[2]), s_f, s_l), innov))
        state = self.lock.state
        if state is LockState.LOST:
            gate = qp.recover_chi2_gate if qp.recover_chi2_gate > 0.0 else math.inf  # under the widened P
        else:
            gate = qp.chi2_gate if c.support > 1 else qp.chi2_gate_single
        if nis > gate:
            answers.failed(FixReason.INNOVATION_GATE, jump, self.odo, innov if c.weight >= qp.guard_w_min else None)
            return answer.refused(FixReason.INNOVATION_GATE, chosen=k, xy=z, yaw_residual=psi[k], sigma_fwd=s_f,
                                  sigma_lat=s_l, nis=nis)
        held = answers.hold(state, innov, jump, Pz, now, self.odo, now - q.capture_t, tick.track_unit)
        if held == "hold":
            answers.failed(FixReason.UNCONFIRMED, jump, self.odo)
            return answer.refused(FixReason.UNCONFIRMED, chosen=k, xy=z, yaw_residual=psi[k], sigma_fwd=s_f,
                                  sigma_lat=s_l, nis=nis)
        if state is LockState.LOST or held == "confirmed":  # relocalise: the candidate replaces the position
            tick.P = tick.P.copy()  # (the jump enters P)
            tick.P[:2, :2] += jump * jump * np.eye(2)
        if scale_cov is not None:  # ... enters the filter where the fix can take it out
            tick.P = tick.P.copy()
            tick.P[:2, :2] += scale_cov
        answers.held = []
        learn = state is LockState.LOCKED and held is None
        if qp.adaptive_fix_noise and learn:  # learn from this fix for the next ones
            self.fix_scale.update(innov, Pz, fix_covariance(float(tick.x[2]), s_f0, s_l0))
        # the answer's rotation measures the true heading at capture (plus.fix_yaw_sigma_rad; 0: gate only)
        heading = (q.heading + float(psi[k]), qp.fix_yaw_sigma_rad) if qp.fix_yaw_sigma_rad > 0.0 else None
        tl.fix(tick, z, s_f, s_l, heading)
        self.scale.pin(tick)
        self._odo_at_fix = max(self._odo_at_fix, self._odo_at_query)  # the query was planned at its capture
        if learn:
            self.report_factor.update(nis)
        # a confirmed jump is a relocalisation: half of it stays in P until confirm_fixes later fixes agree
        answers.settle_lock(LockState.LOST if held == "confirmed" else state, jump, s_f, s_l)
        if tl.history:
            self.feedback(tl.history[-1])
        answers.accepted()
        self._deferred = 0
        self.zero.seen(math.sqrt(max(float(tl.ukf.P[3, 3]), 0.0)))
        if self.q.guard:
            self.guard.reset()
        return answer.accepted(chosen=k, xy=z, yaw_residual=psi[k], sigma_fwd=s_f, sigma_lat=s_l, nis=nis)

    def _defer(self, w: float, P: np.ndarray) -> bool:
        """Whether to leave a weak answer (consensus weight w) unused and ask again (plus.defer_answer)."""
        healthy = self.lock.state is LockState.LOCKED and not self.guard.flagged
        if defer_answer(w, self._deferred, healthy, horizontal_sigma(P), self.odo - self._odo_at_fix, self.q):
            self._deferred += 1
            return True
        return False

    # ------------------------------------------------------------------ outputs
    def report(self, est: Estimate) -> Estimate:
        """The reported estimate: the fixes' variance factor makes the reported accuracy honest while locked and
        while the safety guard agrees; otherwise the filter's own (widened) covariance is reported as it is
        Not while a real GNSS is fused: the factor is learnt from camera fixes and says nothing of the
        receiver's wander, which the GNSS update keeps in P. Rejections that agree keep a floor under it."""
        x = self.timeline.ukf.x
        if (self.q.report_calibration and self.lock.state is LockState.LOCKED and not self.guard.flagged
                and not self.gnss_status.in_use):
            est = dataclasses.replace(est, cov_xy=self.report_factor.factor * est.cov_xy)
        if self.q.speed_scale_consider:
            est = dataclasses.replace(est, cov_xy=est.cov_xy + self.scale.covariance())
        est = est.floored(self.answers.report_floor_m)
        est.extra.update(lock=self.lock.state.value, speed_error=float(x[3]), accel_bias=float(x[4]),
                         compass_bias=float(x[5]) if len(x) > 5 else 0.0, fix_scale=self.fix_scale.scale,
                         map_offset=[float(v) for v in x[6:8]],
                         stationary=self.zero.active)
        return est

    # ------------------------------------------------------------------ other inputs and events
    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane motion as a speed measurement (camera_speed.py)."""
        used = self.camera.add(t0, t1, d_fwd, d_left, sigma_m)
        if used == "used":
            self.scale.camera_used(t1)
        return used

    def after_gnss(self, fix: GnssFix, out: GnssOutcome) -> None:
        self.camera.after_gnss(fix, out)
        if out.used:
            self.scale.pin()

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """The lock events not yet taken (the daemon logs each once)."""
        return self.lock.take_unreported()

    def after_gnss_rollback(self) -> None:
        self.gnss.after_rollback()

    # ------------------------------------------------------------------ a real GNSS: a Kalman update (gnss.py)
    def apply(self, ukf: PlanarUkf, tick: Tick, m: GnssMeasurement) -> None:
        self.gnss.apply(ukf, tick, m)

    def gnss_fused(self, tick: Tick, m: GnssMeasurement) -> None:
        self.gnss.fused_live(tick, m)

    def gnss_anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        return self.gnss.anchor_terms(tick)
