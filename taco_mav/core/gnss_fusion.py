"""Real GNSS in the Localiser (issue 14): the `add_gnss` path both estimators share (a mixin of `Localiser`).

    out = loc.add_gnss(GnssFix(t, xy, vel_en, sigma_h_m, sigma_v_mps))   # ~5 Hz, between filter frames
    out.used, out.reason                                                  # "fused" / "anchored" / "rejected" ...

A reading arrives between filter frames. It is referred to the latest frame (the displacement integrated since
is taken off, the speed and heading change since likewise) and tested by the guard (`gnss_guard.GnssGuard`).
An accepted reading is applied at that frame `fuse_delay_s` later (in batches every `fuse_interval_s`: rewind to
the frame, update, replay, as for a late camera fix), so the guard has seen the readings that followed it before
it moves the estimate: a drag the guard catches within the delay never reaches the output. The measurement is
kept on its frame, so a camera fix's rewind and replay applies it again. When the guard rejects a receiver that
was in use, readings waiting for their turn are dropped and those fused after the frame its failing test
started from are undone (rewind, replay without them).

What "applied" means is the estimator's: paper mode re-anchors (position := the reading, covariance sigma_h^2,
anchor window reset; the preintegrator's position and speed follow; the paper's maths untouched), taco+ makes
a Kalman update of position, speed error and heading (`PlusLocaliser._gnss_apply`), so the speed error,
accelerometer bias and compass bias are calibrated before GNSS is lost.

While the GNSS is healthy camera fixes are asked for only every `camera_interval_s` (`camera_check_s` when the
guard is suspicious): they cross-check the receiver.

Frames and units: GnssFix.xy ENU metres on the origin's UTM grid; vel_en grid east/north m/s (the daemon turns
the true course onto the grid); sigmas 1-sigma m and m/s; times autopilot seconds.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from taco_mav.core.frames import FixOutcome, GnssMeasurement, Tick
from taco_mav.core.gnss_guard import GnssGuard, GuardState, GuardVerdict, filter_offset_variance, receiver_variances
from taco_mav.core.gnss_params import GnssParams
from taco_mav.core.gnss_shadow import Anchor, DeadReckoner, DrSnap
from taco_mav.core.preintegration import wrap_angle
from taco_mav.core.types import GnssFix, GnssOutcome
from taco_mav.core.ukf import fix_covariance

class GnssFusion:
    """The GNSS half of `Localiser` (mixed in; it uses the filter, preintegrator and history)."""

    _gnss_replaces = True  # paper mode: a reading replaces the position (taco+: a Kalman update)

    # ------------------------------------------------------------------ set-up
    def _gnss_init(self) -> None:
        self._gnss_params: GnssParams = self.p.gnss
        self.gnss_guard: GnssGuard | None = None  # made at the first reading
        self._gnss_dr: DeadReckoner | None = None
        self._gnss_snaps: deque[tuple[int, DrSnap]] = deque()  # (frame node, dead reckoner at its end)
        self._gnss_pending: deque[tuple[Tick, GnssMeasurement]] = deque()  # accepted, not yet fused
        self._gnss_flush_t = -math.inf
        self._gnss_last_t = -math.inf
        self._gnss_query_t = -math.inf
        self._gnss_events: list[tuple[float, str, str]] = []
        self._gnss_sigma_h = 1.0  # the last reading's 1-sigma, m
        self._gnss_entry_t = -math.inf  # first accepted reading since the receiver was lost or rejected
        self.gnss_fused = 0  # readings fused so far

    # ------------------------------------------------------------------ the reading
    def add_gnss(self, fix: GnssFix) -> GnssOutcome:
        """One real GNSS reading (see the module docstring). Returns what was done: used with reason "fused"
        (taco+) or "anchored" (paper mode): the guard accepted it and it is applied fuse_delay_s later unless the
        guard rejects the receiver in between; "rejected" (the guard holds the receiver off); "nonfinite";
        "stale" (not after the last reading, or further than max_age_s from the IMU clock); "ignored" (GNSS
        use disabled, or before the first filter frame)."""
        gp = self._gnss_params
        if not gp.enabled or not self._history:
            return GnssOutcome(False, "ignored")
        xy = np.asarray(fix.xy, dtype=float).reshape(-1)
        vel = None if fix.vel_en is None else np.asarray(fix.vel_en, dtype=float).reshape(-1)
        if (xy.shape != (2,) or not np.all(np.isfinite(xy)) or not math.isfinite(fix.t)
                or not (math.isfinite(fix.sigma_h_m) and fix.sigma_h_m > 0.0)
                or (vel is not None and (vel.shape != (2,) or not np.all(np.isfinite(vel))))):
            return GnssOutcome(False, "nonfinite")
        if fix.t <= self._gnss_last_t or abs(self.t - fix.t) > gp.max_age_s:
            return GnssOutcome(False, "stale")
        self._gnss_last_t = fix.t
        if self.gnss_guard is None:
            self.gnss_guard = GnssGuard(gp)
            self._gnss_dr = DeadReckoner(self.t, float(self.pre.theta))
        guard, tick = self.gnss_guard, self._history[-1]
        guard_prev = guard.t_accepted if guard.t_accepted is not None else -math.inf
        meas, z_now = self._gnss_measurement(fix, xy, vel, tick)
        self._gnss_sigma_h = math.sqrt(meas.var_xy)
        dx, dy = self.pre.interval_displacement
        pred = self.ukf.x[:2] + np.array([dx, dy])
        ref, vref = self._gnss_reference(gp.reference_lag_s), self._gnss_reference(gp.velocity_lag_s)
        v = guard.check(self.t, z_now, self._gnss_sigma_h, pred, self.ukf.P[:2, :2].copy(), self._gnss_dr.snap(),
                        None if ref is None else self._gnss_anchor(ref), replace=self._gnss_replaces, vel=vel,
                        sigma_v=max(fix.sigma_v_mps if math.isfinite(fix.sigma_v_mps) else 0.0, gp.sigma_v_min_mps),
                        vel_anchor=None if vref is None else self._gnss_anchor(vref))
        if not v.accept:
            if v.newly_rejected:
                self._gnss_event("gnss_rejected", v)
                self._gnss_pending.clear()
                # undo what was fused since the reference that saw it (a jump or a hold: nothing to undo)
                base = vref if set(v.flags) <= {"velocity"} else ref
                if base is not None and set(v.flags) - {"jump", "hold"}:
                    self._gnss_rollback(base)
            return GnssOutcome(False, "rejected", v.nis, v.window_nis, v.innovation_m)
        if v.reaccepted:
            self._gnss_event("gnss_accepted", v)
        if v.reaccepted or self.t - guard_prev > gp.gap_s:
            self._gnss_entry_t = self.t
        self._gnss_pending.append((tick, meas))
        self._gnss_flush()
        return GnssOutcome(True, "anchored" if self._gnss_replaces else "fused", v.nis, v.window_nis,
                           v.innovation_m)

    def _gnss_measurement(self, fix: GnssFix, xy: np.ndarray, vel: np.ndarray | None,
                          tick: Tick) -> tuple[GnssMeasurement, np.ndarray]:
        """The reading referred to the latest frame, and its position carried to the IMU's now (ENU m)."""
        gp, pre = self._gnss_params, self.pre
        lead = self.t - fix.t  # the reading is this much older than the IMU's now
        z_now = xy + pre.speed * lead * np.array([math.cos(pre.theta), math.sin(pre.theta)])
        dx, dy = pre.interval_displacement
        z_frame = z_now - np.array([dx, dy])
        var_xy = max(fix.sigma_h_m, gp.sigma_h_min_m) ** 2
        speed = course = None
        var_speed = var_course = 0.0
        if vel is not None:
            ground = float(np.hypot(*vel))
            if ground >= gp.min_speed_mps:
                course = math.atan2(vel[1], vel[0])
                if self.p.imu.allow_reverse and abs(wrap_angle(course - pre.theta)) > 0.5 * math.pi:
                    ground, course = -ground, wrap_angle(course + math.pi)
                sv = max(fix.sigma_v_mps if math.isfinite(fix.sigma_v_mps) else 0.0, gp.sigma_v_min_mps)
                # at the frame end: less what the preintegrator gained since (its speed there was
                # speed_end plus what was fed back after the frame)
                speed = ground - (pre.speed - (tick.inc.speed_end + tick.dv_fed))
                var_speed = sv * sv
                course = wrap_angle(course - wrap_angle(pre.theta - pre.interval_heading))
                var_course = max(gp.course_sigma_min_rad, sv / abs(ground)) ** 2
        return GnssMeasurement(fix.t, z_frame, var_xy, speed, var_speed, course, var_course), z_now

    # ------------------------------------------------------------------ fusing, fuse_delay_s late
    def _gnss_flush(self) -> None:
        """Fuse the accepted readings older than fuse_delay_s, in one rewind and replay (at most every
        fuse_interval_s)."""
        gp = self._gnss_params
        if not self._gnss_pending or self.t - self._gnss_flush_t < gp.fuse_interval_s - 1e-9:
            return
        due = []
        while self._gnss_pending and self._gnss_pending[0][1].t <= self.t - gp.fuse_delay_s + 1e-9:
            due.append(self._gnss_pending.popleft())
        due = [(h, m) for h, m in due if any(h is k for k in self._history)]  # frames still in the history
        if not due:
            return
        self._gnss_flush_t = self.t
        for h, m in due:
            h.gnss.append(m)
        base = due[0][0]
        self.ukf.set_state(base.x, base.P)
        for m in (m for h, m in due if h is base):
            self._gnss_apply(base, m)
        self._gnss_settle(base)
        self._gnss_replay_after(base)
        self.gnss_fused += len(due)
        self._gnss_fused_live(due[-1][0], due[-1][1])

    def _gnss_replay_after(self, base: Tick) -> None:
        """Replay the frames after `base` from the filter's current state (which is base's), as `_apply_at`
        does after a late fix: their stored camera fixes and GNSS are applied again."""
        self._reset_anchor()
        pre_x, pre_y = float(self.ukf.x[0]), float(self.ukf.x[1])
        base.window, base.pre_xy = self._window, (pre_x, pre_y)
        later = [h for h in self._history if h.t > base.t]
        self._replay(later, pre_x, pre_y)
        dx, dy = self.pre.interval_displacement
        self.pre.reset_position(float(self.ukf.x[0]) + dx, float(self.ukf.x[1]) + dy)
        if self.record:
            for h in [base, *later]:
                self._graph_x[h.node] = h.x[:3].copy()

    def _gnss_replay(self, tick: Tick) -> None:
        """A replayed frame applies its GNSS measurements again (called at the end of `_advance`)."""
        for m in tick.gnss:
            self._gnss_apply(tick, m)
        self._gnss_settle(tick)

    def _gnss_settle(self, tick: Tick) -> None:
        """After the GNSS updates at `tick`: store the state on it and reset the anchor window (a fix)."""
        tick.x, tick.P = self.ukf.get_state()
        self._reset_anchor()
        tick.window = self._window

    # ------------------------------------------------------------------ paper mode: re-anchoring
    def _gnss_apply(self, tick: Tick, m: GnssMeasurement) -> None:
        """Paper mode: the reading re-anchors the filter at `tick`: position := the reading, position
        covariance := sigma_h^2 I (uncorrelated with the heading)."""
        x, P = self.ukf.get_state()
        x[:2] = m.xy
        P[:2, :] = 0.0
        P[:, :2] = 0.0
        P[:2, :2] = m.var_xy * np.eye(2)
        self.ukf.set_state(x, P)

    def _gnss_fused_live(self, tick: Tick, m: GnssMeasurement) -> None:
        """After a batch, the newest reading's speed re-anchors the preintegrator's (paper mode): the speed
        error at its frame less what later re-anchorings set already, kept as `dv_fed` on the latest frame."""
        if m.speed is None:
            return
        since = sum(h.dv_fed for h in self._history if h.t > tick.t)  # set after that frame already
        new = self.pre.speed + m.speed - (tick.inc.speed_end + tick.dv_fed) - since
        if not self.p.imu.allow_reverse:
            new = max(new, 0.0)
        self._history[-1].dv_fed += new - self.pre.speed
        self.pre.speed = new

    # ------------------------------------------------------------------ the guard's inputs
    def _gnss_imu(self, t: float, dt: float) -> None:
        """One IMU step for the guard's dead reckoner (called from `add_imu`)."""
        if self._gnss_dr is not None:
            self._gnss_dr.add(t, dt, self.pre.accel_fwd, self.pre.theta)

    def _gnss_frame(self, tick: Tick) -> None:
        """A new frame: keep the dead reckoner's snapshot at its end, and fuse what is due (from `_frame`)."""
        if self._gnss_dr is None:
            return
        self._gnss_snaps.append((tick.node, self._gnss_dr.snap()))
        oldest = self._history[0].node
        while self._gnss_snaps and self._gnss_snaps[0][0] < oldest:
            self._gnss_snaps.popleft()
        self._gnss_flush()

    def _gnss_anchor(self, tick: Tick) -> Anchor | None:
        """The filter's state at `tick` as a shadow anchor (None without a snapshot there)."""
        snap = next((s for n, s in self._gnss_snaps if n == tick.node), None)
        if snap is None:
            return None
        speed, bias, beta, sigmas = self._gnss_anchor_terms(tick)
        # its error about the receiver's bias track. Fused GNSS within gap_s before: P less the receiver's bias
        # (which P holds and the later readings share), at least the white noise a GNSS-following filter
        # keeps; else P plus the receiver's bias.
        gp, sh = self._gnss_params, self._gnss_sigma_h
        bias_var = receiver_variances(sh, gp)[1]
        tied = any(h.gnss for h in self._history if tick.t - gp.gap_s <= h.t <= tick.t)
        cov = tick.P[:2, :2] + (-bias_var if tied else bias_var) * np.eye(2)
        w, V = np.linalg.eigh(0.5 * (cov + cov.T))
        cov = (V * np.maximum(w, filter_offset_variance(sh, gp, self._gnss_replaces))) @ V.T
        return Anchor(tick.t, tick.x[:2].copy(), cov, speed, bias, beta, snap, *sigmas,
                      bias_estimated=not self._gnss_replaces)

    def _gnss_anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        """(true-speed estimate m/s, accelerometer bias m/s^2, compass bias rad, their 1-sigmas with the
        heading's) at `tick`'s end. Paper mode has no bias states: its speed is the receiver's (sigma: the last
        reading's speed accuracy), its accelerometer bias unknown (`Anchor.bias_estimated`)."""
        m = next((m for m in reversed(tick.gnss) if m.speed is not None), None)
        sv = math.sqrt(m.var_speed) if m is not None else self._gnss_params.sigma_v_min_mps
        return float(tick.inc.speed_end + tick.dv_fed), 0.0, 0.0, (sv, 0.0, 0.0)

    def _gnss_reference(self, lag: float) -> Tick | None:
        """The frame a shadow of the guard starts from: the newest at least `lag` seconds old (the oldest in the
        history while there is none), or None before the dead reckoner's first frame. While the receiver is in
        use only frames since it was last lost or rejected count (the filter before had not met it)."""
        first = self._gnss_snaps[0][0] if self._gnss_snaps else None
        in_use = self.gnss_guard is not None and self.gnss_guard.state is GuardState.OK
        since = self._gnss_entry_t if in_use else -math.inf
        best = None
        for h in self._history:
            if first is None or h.node < first or h.t < since - 1e-6:
                continue
            if best is None or h.t <= self.t - lag + 1e-6:
                best = h
            else:
                break
        return best

    def _gnss_fix_outcome(self, outcome: FixOutcome) -> None:
        """A camera fix answered: cross-check it with the GNSS readings around its capture (from `_log`)."""
        g = self.gnss_guard
        if g is None or outcome.xy is None or outcome.reason not in ("accepted", "innovation_gate"):
            return
        tick = next((h for h in self._history if abs(h.t - outcome.capture_t) < 1e-6), None)
        anchor = self._gnss_anchor(self._history[-1]) if self._history else None
        if anchor is None:
            return
        theta = float(tick.x[2]) if tick is not None else float(self.ukf.x[2])
        R = fix_covariance(theta, max(outcome.sigma_fwd, 1e-3), max(outcome.sigma_lat, 1e-3))
        g.camera_check(outcome.capture_t, np.asarray(outcome.xy, dtype=float), R, anchor)

    # ------------------------------------------------------------------ rejection
    def _gnss_rollback(self, base: Tick) -> None:
        """Undo the GNSS fused after frame `base` (the guard's reference): rewind there and replay without
        them (camera fixes stay)."""
        later = [h for h in self._history if h.t > base.t]
        if not any(h.gnss for h in later):
            return
        for h in later:
            h.gnss = []
        self.ukf.set_state(base.x, base.P)
        self._gnss_replay_after(base)
        self._gnss_after_rollback(later)
        if self.gnss_guard is not None:
            self.gnss_guard.hold_anchor = self._gnss_anchor(base)

    def _gnss_after_rollback(self, later: list[Tick]) -> None:
        """Paper mode keeps the preintegrator's speed: without a bias state, integrating the accelerometer
        from the rewound frame drifts more than a receiver's speed a few seconds old."""

    # ------------------------------------------------------------------ camera duty while GNSS is healthy
    def _gnss_plan(self, plan: Any) -> Any:
        """Filter the trigger's plan (reason, bias, offsets): while the GNSS is healthy a camera fix is due
        every camera_interval_s only (camera_check_s while the guard is suspicious). From `_maybe_trigger`."""
        g, gp = self.gnss_guard, self._gnss_params
        if plan is not None and g is not None and g.healthy_at(self.t):
            since = self.t - self._gnss_query_t
            if since < gp.camera_interval_s and not (g.suspect and since >= gp.camera_check_s):
                return None
            plan = ("gnss_check", plan[1], plan[2])
        if plan is not None:
            self._gnss_query_t = self.t
        return plan

    # ------------------------------------------------------------------ outputs
    @property
    def gnss_state(self) -> str:
        """"none" (no reading yet), "ok" (in use) or "rejected" (held off by the guard)."""
        return "none" if self.gnss_guard is None else self.gnss_guard.state.value

    @property
    def gnss_in_use(self) -> bool:
        """A reading accepted within the guard's gap_s of now."""
        return self.gnss_guard is not None and self.gnss_guard.healthy_at(self.t)

    def take_gnss_events(self) -> list[tuple[float, str, str]]:
        """(t, kind, detail) of "gnss_rejected" / "gnss_accepted" since the last call (detail: the figures)."""
        out, self._gnss_events = self._gnss_events, []
        return out

    def _gnss_event(self, kind: str, v: GuardVerdict) -> None:
        self._gnss_events.append((self.t, kind, v.detail))


__all__ = ["GnssFusion", "GnssMeasurement"]
