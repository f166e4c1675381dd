"""Real GNSS in the Localiser: the `add_gnss` path both estimator modes share, a part the Localiser owns
(`loc.gnss`).

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

What "applied" means is the estimator's (a `GnssCorrection` through its `GnssUpdate`): paper mode re-anchors (position := the reading,
covariance sigma_h^2, anchor window reset; the preintegrator's position and speed follow; the paper's maths
untouched), taco+ makes a Kalman update of position, speed error and heading (plus/gnss.py), so the speed error, accelerometer bias and compass bias are calibrated before GNSS is lost.

While the GNSS is healthy camera fixes are asked for only every `camera_interval_s` (`camera_check_s` when the
guard is suspicious): they cross-check the receiver.

Frames and units: GnssFix.xy ENU metres on the origin's UTM grid; vel_en grid east/north m/s (the daemon turns
the true course onto the grid); sigmas 1-sigma m and m/s; times autopilot seconds.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from typing import TYPE_CHECKING

from taco_mav.core.corrections import GnssCorrection
from taco_mav.core.frames import FixOutcome, FixReason, GnssMeasurement, Tick
from taco_mav.core.gnss.guard import (
    GnssGuard,
    GuardState,
    GuardVerdict,
    filter_offset_variance,
    receiver_variances,
)
from taco_mav.core.gnss.params import GnssParams
from taco_mav.core.gnss.shadow import Anchor, DeadReckoner, DrSnap
from taco_mav.core.timeline import Timeline
from taco_mav.core.preintegration import wrap_angle
from taco_mav.core.types import Estimate, GnssFix, GnssOutcome
from taco_mav.core.ukf import fix_covariance

if TYPE_CHECKING:
    from taco_mav.core.estimator import Aids, GnssPolicy, Plan


class GnssFusion:
    """The real-GNSS fusion on the Localiser's `timeline` (see the module docstring): it owns the guard, the
    guard's dead reckoner and the readings waiting for their turn; it rewinds and replays through the timeline,
    and what a reading does to the filter is the estimator's (`serve`)."""

    def __init__(self, timeline: Timeline, params: GnssParams) -> None:
        self.timeline, self.p = timeline, params
        self.update: GnssPolicy
        self.aids: Aids | None = None
        self.guard: GnssGuard | None = None  # made at the first reading
        self._dr: DeadReckoner | None = None
        self._snaps: deque[tuple[int, DrSnap]] = deque()  # (frame node, dead reckoner at its end)
        self._pending: deque[tuple[Tick, GnssMeasurement]] = deque()  # accepted, not yet fused
        self._flush_t = -math.inf
        self._last_t = -math.inf
        self._query_t = -math.inf
        self._events: list[tuple[float, str, str]] = []
        self._sigma_h = 1.0  # the last reading's 1-sigma, m
        self._entry_t = -math.inf  # first accepted reading since the receiver was lost or rejected
        self.fused = 0  # readings fused so far

    def serve(self, update: GnssPolicy, aids: Aids | None) -> None:
        """What a reading does to the estimator's filter, and the estimator's aiding (told of a rollback)."""
        self.update, self.aids = update, aids

    # ------------------------------------------------------------------ the reading
    def add(self, fix: GnssFix) -> GnssOutcome:
        """One real GNSS reading (see the module docstring). Returns what was done: used with reason "fused"
        (taco+) or "anchored" (paper mode): the guard accepted it and it is applied fuse_delay_s later unless the
        guard rejects the receiver in between; "rejected" (the guard holds the receiver off); "nonfinite";
        "stale" (not after the last reading, or further than max_age_s from the IMU clock); "ignored" (GNSS
        use disabled, or before the first filter frame)."""
        gp = self.p
        if not gp.enabled or not self.timeline.history:
            return GnssOutcome(False, "ignored")
        xy = np.asarray(fix.xy, dtype=float).reshape(-1)
        vel = None if fix.vel_en is None else np.asarray(fix.vel_en, dtype=float).reshape(-1)
        if (xy.shape != (2,) or not np.all(np.isfinite(xy)) or not math.isfinite(fix.t)
                or not (math.isfinite(fix.sigma_h_m) and fix.sigma_h_m > 0.0)
                or (vel is not None and (vel.shape != (2,) or not np.all(np.isfinite(vel))))):
            return GnssOutcome(False, "nonfinite")
        if fix.t <= self._last_t or abs(self.timeline.t - fix.t) > gp.max_age_s:
            return GnssOutcome(False, "stale")
        self._last_t = fix.t
        if self.guard is None:
            self.guard = GnssGuard(gp)
            self._dr = DeadReckoner(self.timeline.t, float(self.timeline.pre.theta))
        guard, tick = self.guard, self.timeline.history[-1]
        guard_prev = guard.t_accepted if guard.t_accepted is not None else -math.inf
        meas, z_now = self._measurement(fix, xy, vel, tick)
        self._sigma_h = math.sqrt(meas.var_xy)
        dx, dy = self.timeline.pre.interval_displacement
        pred = self.timeline.ukf.x[:2] + np.array([dx, dy])
        ref, vref = self._reference(gp.reference_lag_s), self._reference(gp.velocity_lag_s)
        v = guard.check(self.timeline.t, z_now, self._sigma_h, pred, self.timeline.ukf.P[:2, :2].copy(), self._dr.snap(),
                        None if ref is None else self._anchor(ref), replace=self.update.replaces, vel=vel,
                        sigma_v=max(fix.sigma_v_mps if math.isfinite(fix.sigma_v_mps) else 0.0, gp.sigma_v_min_mps),
                        vel_anchor=None if vref is None else self._anchor(vref))
        if not v.accept:
            if v.newly_rejected:
                self._event("gnss_rejected", v)
                self._pending.clear()
                # undo what was fused since the reference that saw it (a jump or a hold: nothing to undo)
                base = vref if set(v.flags) <= {"velocity"} else ref
                if base is not None and set(v.flags) - {"jump", "hold"}:
                    self._rollback(base)
            return GnssOutcome(False, "rejected", v.nis, v.window_nis, v.innovation_m)
        if v.reaccepted:
            self._event("gnss_accepted", v)
        if v.reaccepted or self.timeline.t - guard_prev > gp.gap_s:
            self._entry_t = self.timeline.t
        self._pending.append((tick, meas))
        self._flush()
        return GnssOutcome(True, "anchored" if self.update.replaces else "fused", v.nis, v.window_nis,
                           v.innovation_m)

    def _measurement(self, fix: GnssFix, xy: np.ndarray, vel: np.ndarray | None,
                          tick: Tick) -> tuple[GnssMeasurement, np.ndarray]:
        """The reading referred to the latest frame, and its position carried to the IMU's now (ENU m)."""
        gp, pre = self.p, self.timeline.pre
        lead = self.timeline.t - fix.t  # the reading is this much older than the IMU's now
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
                if self.timeline.p.imu.allow_reverse and abs(wrap_angle(course - pre.theta)) > 0.5 * math.pi:
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
    def _flush(self) -> None:
        """Fuse the accepted readings older than fuse_delay_s, in one rewind and replay (at most every
        fuse_interval_s)."""
        gp = self.p
        if not self._pending or self.timeline.t - self._flush_t < gp.fuse_interval_s - 1e-9:
            return
        due = []
        while self._pending and self._pending[0][1].t <= self.timeline.t - gp.fuse_delay_s + 1e-9:
            due.append(self._pending.popleft())
        due = [(h, m) for h, m in due if any(h is k for k in self.timeline.history)]  # frames still in the history
        if not due:
            return
        self._flush_t = self.timeline.t
        self.timeline.correct_batch(due[0][0], [(h, GnssCorrection(m, self.update)) for h, m in due])
        self.fused += len(due)
        self.update.fused(due[-1][0], due[-1][1])

    # ------------------------------------------------------------------ the guard's inputs
    def on_imu(self, t: float, dt: float) -> None:
        """One IMU step for the guard's dead reckoner (called from `add_imu`)."""
        if self._dr is not None:
            self._dr.add(t, dt, self.timeline.pre.accel_fwd, self.timeline.pre.theta)

    def on_frame(self, tick: Tick) -> None:
        """A new frame: keep the dead reckoner's snapshot at its end, and fuse what is due (from `_frame`)."""
        if self._dr is None:
            return
        self._snaps.append((tick.node, self._dr.snap()))
        oldest = self.timeline.history[0].node
        while self._snaps and self._snaps[0][0] < oldest:
            self._snaps.popleft()
        self._flush()

    def _snap(self, tick: Tick) -> DrSnap | None:
        """The dead reckoner at the end of frame `tick` (None without a snapshot there)."""
        return next((s for n, s in self._snaps if n == tick.node), None)

    def _anchor(self, tick: Tick) -> Anchor | None:
        """The filter's state at `tick` as a shadow anchor (None without a snapshot there)."""
        snap = self._snap(tick)
        if snap is None:
            return None
        speed, bias, beta, sigmas = self.update.anchor_terms(tick)
        # its error about the receiver's bias track. Fused GNSS within gap_s before: P less the receiver's bias
        # (which P holds and the later readings share), at least the white noise a GNSS-following filter
        # keeps; else P plus the receiver's bias.
        gp, sh = self.p, self._sigma_h
        bias_var = receiver_variances(sh, gp)[1]
        tied = any(h.gnss for h in self.timeline.history if tick.t - gp.gap_s <= h.t <= tick.t)
        cov = tick.P[:2, :2] + (-bias_var if tied else bias_var) * np.eye(2)
        w, V = np.linalg.eigh(0.5 * (cov + cov.T))
        cov = (V * np.maximum(w, filter_offset_variance(sh, gp, self.update.replaces))) @ V.T
        return Anchor(tick.t, tick.x[:2].copy(), cov, speed, bias, beta, snap, *sigmas,
                      bias_estimated=not self.update.replaces)

    def _reference(self, lag: float) -> Tick | None:
        """The frame a shadow of the guard starts from: the newest at least `lag` seconds old (the oldest in the
        history while there is none), or None before the dead reckoner's first frame. While the receiver is in
        use only frames since it was last lost or rejected count (the filter before had not met it)."""
        first = self._snaps[0][0] if self._snaps else None
        in_use = self.guard is not None and self.guard.state is GuardState.OK
        since = self._entry_t if in_use else -math.inf
        best = None
        for h in self.timeline.history:
            if first is None or h.node < first or h.t < since - 1e-6:
                continue
            if best is None or h.t <= self.timeline.t - lag + 1e-6:
                best = h
            else:
                break
        return best

    def on_fix_outcome(self, outcome: FixOutcome) -> None:
        """A camera fix answered: cross-check it with the GNSS readings around its capture (from `_log`)."""
        g = self.guard
        checked = (FixReason.ACCEPTED, FixReason.INNOVATION_GATE, FixReason.REFUTED)
        if g is None or outcome.xy is None or outcome.reason not in checked:
            return
        tick = next((h for h in self.timeline.history if abs(h.t - outcome.capture_t) < 1e-6), None)
        anchor = self._anchor(self.timeline.history[-1]) if self.timeline.history else None
        if anchor is None:
            return
        theta = float(tick.x[2]) if tick is not None else float(self.timeline.ukf.x[2])
        R = fix_covariance(theta, max(outcome.sigma_fwd, 1e-3), max(outcome.sigma_lat, 1e-3))
        snap = self._snap(tick) if tick is not None else None
        g.camera_check(outcome.capture_t, np.asarray(outcome.xy, dtype=float), R, anchor, snap)

    # ------------------------------------------------------------------ rejection
    def _rollback(self, base: Tick) -> None:
        """Undo the GNSS fused after frame `base` (the guard's reference): rewind there and replay without
        them (camera fixes stay)."""
        if not self.timeline.forget(base, Tick.drop_gnss):
            return
        if self.aids is not None:
            self.aids.after_gnss_rollback()
        if self.guard is not None:
            self.guard.hold_anchor = self._anchor(base)

    # ------------------------------------------------------------------ camera duty while GNSS is healthy
    def plan(self, plan: Plan | None) -> Plan | None:
        """Filter the trigger's plan (reason, bias, offsets): while the GNSS is healthy a camera fix is due
        every camera_interval_s (camera_check_s while the guard is suspicious), and only then. From
        `_maybe_trigger`."""
        g, gp = self.guard, self.p
        if g is not None and g.healthy_at(self.timeline.t):
            since = self.timeline.t - self._query_t
            if since < gp.camera_interval_s and not (g.suspect and since >= gp.camera_check_s):
                return None
            # due whether or not the mode's trigger wants a fix (fused readings keep its covariance small): one
            # crop where the filter is, unless the trigger planned a search
            plan = ("gnss_check", plan[1], plan[2]) if plan is not None else ("gnss_check", 0.0, np.zeros((1, 2)))
        if plan is not None:
            self._query_t = self.timeline.t
        return plan

    # ------------------------------------------------------------------ outputs
    @property
    def state(self) -> str:
        """"none" (no reading yet), "ok" (in use) or "rejected" (held off by the guard)."""
        return "none" if self.guard is None else self.guard.state.value

    @property
    def camera_refuted(self) -> bool:
        """The readings refute the camera: it never agreed with them and its last checks disagreed
        (`GnssGuard.camera_refuted`); False before any reading."""
        return self.guard is not None and self.guard.camera_refuted

    @property
    def in_use(self) -> bool:
        """A reading accepted within the guard's gap_s of now."""
        return self.guard is not None and self.guard.healthy_at(self.timeline.t)

    def report(self, est: Estimate) -> Estimate:
        """The reported estimate while a receiver is in use: its horizontal 1-sigma at least the guard's camera
        floor (`GnssGuard.camera_floor_m`: the last camera check's distance from the readings). Unchanged
        otherwise."""
        if self.guard is None or not self.in_use:
            return est
        return est.floored(self.guard.camera_floor_m)

    def take_events(self) -> list[tuple[float, str, str]]:
        """(t, kind, detail) of "gnss_rejected" / "gnss_accepted" since the last call (detail: the figures)."""
        out, self._events = self._events, []
        return out

    def _event(self, kind: str, v: GuardVerdict) -> None:
        self._events.append((self.timeline.t, kind, v.detail))


__all__ = ["GnssFusion"]
