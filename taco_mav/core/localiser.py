"""The Localiser: the TACO pipeline (paper Fig. 2) as one object that the offline evaluator and the live daemon both
drive, in either estimator mode.

    loc = Localiser(params, t0, heading=..., speed=...)
    loc.add_imu(sample)            # any rate, irregular dt; frame-rate UKF predict inside
    q = loc.poll_query()           # a FixQuery when the trigger fired (capture time, centre, 5 crop centres)
    loc.add_fix(q.query_id, five)  # the matcher's five MatchResults, possibly late: rewind, update, replay
    loc.estimate()                 # Estimate(t, xy, theta, speed, cov_xy, ...)
    loc.smoothed()                 # Pose2 smoother over the whole run (offline)

The Localiser owns the pipeline every mode shares: the preintegrator, the UKF, the bounded frame history that a
late fix or GNSS reading rewinds to and replays, the query in flight, the real-GNSS fusion (`gnss.fusion`) and
the offline records. What differs between the paper's method and taco+ (the filter's noise, the trigger, what an
answer does, the reported accuracy) is its `mode`, chosen by the parameters: `PaperMode` (paper.py) when
params.plus is None, else `PlusMode` (plus/mode.py); both answer the `Mode` protocol (mode.py), so callers never
ask which one they hold.

World frame: ENU metres relative to the origin (the start-up GNSS reading); heading ENU radians; autopilot s.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from taco_mav.core.error_model import (
    AnchorWindow,
    ErrorTerms,
    HighPass,
    MomentAccumulator,
    error_terms,
)
from taco_mav.core.frames import FixOutcome, Tick
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.mode import Mode
from taco_mav.core.paper import PaperMode
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.mode import PlusMode
from taco_mav.core.preintegration import Preintegrator, wrap_angle
from taco_mav.core.search import search_centres
from taco_mav.core.smoother import FixNode, SmoothResult, smooth
from taco_mav.core.types import (
    Estimate,
    FixQuery,
    GnssFix,
    GnssOutcome,
    ImuSample,
    MatchResult,
    horizontal_sigma,
)
from taco_mav.core.ukf import fix_covariance, fix_sigmas


@dataclass
class _Pending:
    query: FixQuery
    issued_t: float
    x_at_capture: np.ndarray


class Localiser:
    """The TACO pipeline in paper mode or taco+ (`mode`), plus real GNSS while it is honest (`add_gnss`). All times
    in autopilot seconds."""

    def __init__(self, params: LocaliserParams, t0: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0,
                 speed: float = 0.0, record: bool = True, heading_offset: float = 0.0) -> None:
        """t0: start time, s; (x, y): start position, ENU metres; heading: ENU grid heading, rad; speed: m/s
        (from the start-up GNSS reading); heading_offset: UTM meridian convergence, rad, added to every compass
        heading; record: keep the online track, outcomes and smoother inputs (offline evaluation)."""
        self.p = params
        self.frame_dt = 1.0 / params.imu.frame_rate_hz
        self.record = record
        self.pre = Preintegrator.from_params(params.imu, t0, x, y, heading, speed, heading_offset)
        self.highpass = HighPass(params.imu.accel_highpass_hz)
        self._interval_residual = MomentAccumulator()
        self.t = t0
        self._next_tick = t0 + self.frame_dt
        self._window = AnchorWindow()
        self.terms = ErrorTerms(0.0, 0.0, 0.0)  # the error model's terms at the last frame (m)
        self.last_fix_t = t0  # capture time of the last answered query (on arrival: its arrival), s
        self._query_id = 0
        self._ready: FixQuery | None = None
        self._pending: _Pending | None = None
        frames = int(math.ceil(params.latency.history_s * params.imu.frame_rate_hz))
        self.history: deque[Tick] = deque(maxlen=max(2, frames + 2))  # the frames a late answer rewinds to
        self._nodes = 0
        # Offline records (record=True): online track, smoother inputs, outcomes.
        self.track: list[tuple[float, float, float, float, float, float, float]] = []  # t, x, y, th, Pxx, Pxy, Pyy
        self._graph_x: list[np.ndarray] = [np.array([x, y, heading])]
        self._graph_inc: list[tuple[float, float, float]] = []
        self._graph_sigma: list[float] = []
        self._graph_fixes: dict[int, FixNode] = {}
        self.outcomes: list[FixOutcome] = []
        self.queries: list[FixQuery] = []
        self.mode: Mode = PaperMode(self) if params.plus is None else PlusMode(self, params.plus)
        self.ukf = self.mode.make_ukf(x, y, heading)
        self._record_track(t0)
        self.gnss = GnssFusion(self, params.gnss, self.mode)

    # ------------------------------------------------------------------ IMU path
    def add_imu(self, sample: ImuSample) -> None:
        """Integrate one IMU sample (FRD specific force, gyro, NED attitude); at each frame boundary run the
        UKF predict on the accumulated increment and evaluate the trigger."""
        fresh = sample.t > self.pre.t
        self.mode.before_imu(fresh)
        dt = self.pre.add(sample)
        if dt > 0.0:
            self.t = sample.t
            self.gnss.on_imu(sample.t, dt)
            self._interval_residual.add(self.highpass.step(self.pre.accel_fwd, dt))
            # A frame closes at the sample nearest its slot (within half a sample interval, at most a quarter
            # period), so timestamp jitter (KITTI's 10 Hz OXTS wanders by ~+-10 ms) neither skips nor doubles
            # frames.
            tol = min(0.25 * self.frame_dt, 0.5 * dt)
            if self.t >= self._next_tick - tol:
                while self._next_tick <= self.t + tol:
                    self._next_tick += self.frame_dt
                self._frame()
        if fresh:
            self.mode.after_imu(sample)

    def _frame(self) -> None:
        theta_start = self.pre.interval_heading
        inc = self.pre.take_increment()
        tick = Tick(self._nodes + 1, self.t, inc, self._interval_residual.take(), theta_start)
        self.mode.open_tick(tick)
        self._advance(tick, self.pre.x, self.pre.y)
        self._nodes += 1
        self.history.append(tick)
        self.mode.close_tick(tick)
        if self.record:
            self._graph_x.append(tick.x[:3].copy())
            self._graph_inc.append((inc.d_fwd, inc.d_left, inc.d_theta))
            self._graph_sigma.append(self.mode.odometry_sigma(tick))
            self._record_track(self.t)
        self.gnss.on_frame(tick)
        self._maybe_trigger()

    def _advance(self, tick: Tick, pre_x: float, pre_y: float) -> None:
        """Predict + compass update for one frame, starting from the current UKF state and anchor window."""
        inc = tick.inc
        self._window = self._window.extend(inc.dt, inc.distance, tick.residual)
        d_div = math.hypot(self.ukf.x[0] - pre_x, self.ukf.x[1] - pre_y)
        em = self.p.error_model
        terms = error_terms(self._window, d_div, self.p.imu.gyro_arw, em.cross_k, em.along_k, em.divergence_k)
        self.mode.predict(tick, terms)
        self.ukf.update_heading(inc.theta_end, self.p.ukf.compass_sigma_rad)
        self.mode.after_heading(tick)
        if tick.fix is not None:
            self.ukf.update_position(*tick.fix)
        if tick.fix_heading is not None:
            self.ukf.update_true_heading(*tick.fix_heading)
        self.terms = terms
        tick.terms, tick.window, tick.pre_xy = terms, self._window, (pre_x, pre_y)
        tick.x, tick.P = self.ukf.get_state()
        if tick.gnss:
            self.gnss.replay(tick)

    # ------------------------------------------------------------------ trigger
    def _maybe_trigger(self) -> None:
        if self._pending is not None:
            if self.t - self._pending.issued_t < self.p.trigger.query_timeout_s:
                return
            self._pending = None  # unanswered: drop it so the pipeline can ask again
        if self._ready is not None:
            return
        plan = self.gnss.plan(self.mode.plan_search())
        if plan is None:
            return
        reason, bias, offsets = plan
        theta = float(self.pre.theta)
        centre, crops = search_centres(self.ukf.fix_prediction()[0], theta, bias, offsets)  # in the map
        self._query_id += 1
        self._ready = FixQuery(self._query_id, self.t, centre, theta, offsets, crops, self.terms.epsilon, reason)

    def poll_query(self) -> FixQuery | None:
        """The query the trigger produced, once (None when there is none). At most one is in flight."""
        q, self._ready = self._ready, None
        if q is not None:
            self._pending = _Pending(q, self.t, self.ukf.x.copy())
            if self.record:
                self.queries.append(q)
        return q

    def adopt_query(self, q: FixQuery) -> None:
        """Take another Localiser's query as this one's in flight, so that its answer (`add_fix`) updates this
        filter too: a shadow twin (the daemon's `--shadow`) fed the same camera fixes as the filter it runs beside.
        The answer is applied to this filter's own state, at the query's capture time."""
        self._ready = None
        self._pending = _Pending(q, self.t, self.ukf.x.copy())

    def cancel_query(self, query_id: int) -> None:
        """Give up on an in-flight query (matcher failed); the time counter is not reset."""
        if self._pending is not None and self._pending.query.query_id == query_id:
            self._pending = None

    @property
    def query_in_flight(self) -> bool:
        return self._pending is not None

    # ------------------------------------------------------------------ answers
    def add_fix(self, query_id: int, results: Sequence[MatchResult | None]) -> FixOutcome:
        """Hand back the matcher's results for a query (same order as its crop centres; None for a crop that
        could not be matched, e.g. off the map). What an answer does is the mode's (paper: the best candidate
        behind the yaw gate; taco+: consensus, gates and lock); it is applied at its capture time (rewind,
        update, replay) unless params.latency.apply_on_arrival."""
        return self.mode.add_fix(query_id, results)

    def take_pending(self, query_id: int, results: Sequence[MatchResult | None]) -> FixQuery | FixOutcome:
        """The in-flight query these results answer, or the outcome when they answer none or hold nothing."""
        pending = self._pending
        if pending is None or pending.query.query_id != query_id:
            return self.log(FixOutcome(query_id, False, "unknown_query", float("nan"), self.t))
        self._pending = None
        q = pending.query
        if not any(r is not None for r in results):
            self.last_fix_t = max(self.last_fix_t, self.t if self.p.latency.apply_on_arrival else q.capture_t)
            return self.log(FixOutcome(query_id, False, "no_results", q.capture_t, self.t))
        return q

    def fix_sigmas(self, w: float, anisotropic: bool | None = None) -> tuple[float, float]:
        """Body-frame fix sigmas (forward, lateral), metres, from the match weight (Sec. III-F); anisotropic:
        None for ukf.anisotropic, False for both the mean of the two."""
        u = self.p.ukf
        return fix_sigmas(w, u.fix_fwd_num, u.fix_fwd_min_m, u.fix_fwd_max_m, u.fix_lat_num, u.fix_lat_min_m,
                          u.fix_lat_max_m, u.anisotropic if anisotropic is None else anisotropic)

    def capture_tick(self, q: FixQuery) -> Tick | None:
        """The history frame a fix for `q` applies at: the latest (on arrival) or the capture frame."""
        if self.p.latency.apply_on_arrival:
            return self.history[-1] if self.history else None
        return next((h for h in self.history if abs(h.t - q.capture_t) < 1e-6), None)

    def fuse(self, tick: Tick | None, xy: np.ndarray, s_f: float, s_l: float,
             heading: tuple[float, float] | None = None) -> float:
        """Apply a fix (ENU m, body sigmas m; taco+: with the true heading it measures, (ENU rad, 1-sigma rad)) on
        arrival or at its capture frame `tick` (then required), record it for the smoother; returns the NIS."""
        if self.p.latency.apply_on_arrival:
            nis = self._apply_now(xy, s_f, s_l, tick, heading)
        else:
            assert tick is not None
            nis = self._apply_at(tick, xy, s_f, s_l, heading)
        if self.record and tick is not None:
            self._graph_fixes[tick.node] = FixNode(tick.node, xy.copy(), s_f, s_l)
        return nis

    def _apply_now(self, xy: np.ndarray, s_f: float, s_l: float, tick: Tick | None,
                   heading: tuple[float, float] | None = None) -> float:
        R = fix_covariance(float(self.ukf.x[2]), s_f, s_l)
        nis = self.ukf.update_position(xy, R)
        if heading is not None:
            self.ukf.update_true_heading(*heading)
        if tick is not None:
            tick.fix, tick.fix_heading = (xy.copy(), R), heading
            tick.x, tick.P = self.ukf.get_state()
        self._reset_anchor()
        dx, dy = self.pre.interval_displacement
        self.pre.reset_position(float(self.ukf.x[0]) + dx, float(self.ukf.x[1]) + dy)
        if self.record and tick is not None:
            self._graph_x[tick.node] = tick.x[:3].copy()
        return nis

    def _apply_at(self, tick: Tick, xy: np.ndarray, s_f: float, s_l: float,
                  heading: tuple[float, float] | None = None) -> float:
        """Rewind to `tick`, update there, reset the anchor there, replay the later frames."""
        self.ukf.set_state(tick.x, tick.P)
        R = fix_covariance(float(tick.x[2]), s_f, s_l)
        nis = self.ukf.update_position(xy, R)
        if heading is not None:
            self.ukf.update_true_heading(*heading)
        tick.fix, tick.fix_heading = (xy.copy(), R), heading
        tick.x, tick.P = self.ukf.get_state()
        self._reset_anchor()  # the replay below re-extends the window and recomputes the terms
        pre_x, pre_y = float(tick.x[0]), float(tick.x[1])
        tick.window, tick.pre_xy = self._window, (pre_x, pre_y)
        later = [h for h in self.history if h.t > tick.t]
        pre_x, pre_y = self._replay(later, pre_x, pre_y)
        dx, dy = self.pre.interval_displacement
        self.pre.reset_position(pre_x + dx, pre_y + dy)
        if self.record:
            for h in [tick, *later]:
                self._graph_x[h.node] = h.x[:3].copy()
        return nis

    def replay_after(self, base: Tick) -> None:
        """Replay the frames after `base` from the filter's current state (which is base's), as `_apply_at` does
        after a late fix: their stored camera fixes and GNSS are applied again (a GNSS batch, a rollback)."""
        self._reset_anchor()
        pre_x, pre_y = float(self.ukf.x[0]), float(self.ukf.x[1])
        base.window, base.pre_xy = self._window, (pre_x, pre_y)
        later = [h for h in self.history if h.t > base.t]
        self._replay(later, pre_x, pre_y)
        dx, dy = self.pre.interval_displacement
        self.pre.reset_position(float(self.ukf.x[0]) + dx, float(self.ukf.x[1]) + dy)
        if self.record:
            for h in [base, *later]:
                self._graph_x[h.node] = h.x[:3].copy()

    def settle(self, tick: Tick) -> None:
        """After measurement updates at `tick` outside a frame's advance (GNSS): store the state on it and reset
        the anchor window there, as a fix does."""
        tick.x, tick.P = self.ukf.get_state()
        self._reset_anchor()
        tick.window = self._window

    def _replay(self, later: list[Tick], pre_x: float, pre_y: float) -> tuple[float, float]:
        """Advance the history frames `later` again from the filter's current state, the dead-reckoned
        position carried from (pre_x, pre_y) ENU m along their increments; returns where it ends."""
        for h in later:
            c, s = math.cos(h.theta_start), math.sin(h.theta_start)
            pre_x += c * h.inc.d_fwd - s * h.inc.d_left
            pre_y += s * h.inc.d_fwd + c * h.inc.d_left
            self._advance(h, pre_x, pre_y)
        return pre_x, pre_y

    def _reset_anchor(self) -> None:
        self._window = AnchorWindow()
        self.terms = ErrorTerms(0.0, 0.0, 0.0)

    def log(self, outcome: FixOutcome) -> FixOutcome:
        """Record what became of an answer (offline) and let the GNSS guard cross-check it; returns it."""
        if self.record:
            self.outcomes.append(outcome)
        self.gnss.on_fix_outcome(outcome)
        return outcome

    # ------------------------------------------------------------------ other inputs
    @property
    def takes_ground_motion(self) -> bool:
        """Whether `add_ground_motion` is used (taco+: a speed measurement); the daemon skips the work if not."""
        return self.mode.takes_ground_motion

    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane motion between t0 and t1 (autopilot s; metres in frame 0's body axes) as a
        speed measurement (taco+; see plus/camera_speed.py); paper mode has no speed state: "ignored"."""
        return self.mode.add_ground_motion(t0, t1, d_fwd, d_left, sigma_m)

    def set_drive_command(self, t: float, driving: bool) -> None:
        """Whether the autopilot drives at autopilot time t (s): taco+ vetoes its zero-velocity updates while it
        does; paper mode ignores it."""
        self.mode.set_drive_command(t, driving)

    def add_gnss(self, fix: GnssFix) -> GnssOutcome:
        """One real GNSS reading (see gnss/fusion.py); taco+ also checks its ground speed against the camera's."""
        out = self.gnss.add(fix)
        self.mode.after_gnss(fix, out)
        return out

    @property
    def gnss_state(self) -> str:
        """"none" (no reading yet), "ok" (in use) or "rejected" (held off by the guard)."""
        return self.gnss.state

    @property
    def gnss_in_use(self) -> bool:
        """A reading accepted within the guard's gap_s of now."""
        return self.gnss.in_use

    def take_gnss_events(self) -> list[tuple[float, str, str]]:
        """(t, kind, detail) of "gnss_rejected" / "gnss_accepted" since the last call (detail: the figures)."""
        return self.gnss.take_events()

    @property
    def lock_events(self) -> list[tuple[float, str, str]]:
        """(t, kind, detail) of every lock event (taco+: lock_lost / relocalised / relock_failed / recovered ...);
        paper mode keeps no lock."""
        return self.mode.lock_events()

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """Lock events not yet taken, (t s, kind, detail) each (the daemon logs each once)."""
        return self.mode.take_lock_events()

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> Estimate:
        """The current estimate: the filter's (`filter_estimate`) with the mode's reported accuracy (taco+: the
        fixes' variance factor, floors) and its state in `extra`; while a receiver is fused, at least what the
        last camera check saw of its error (`GnssFusion.report`)."""
        return self.gnss.report(self.mode.estimate(self.filter_estimate()))

    def filter_estimate(self) -> Estimate:
        """The filter's own estimate: UKF position and heading at the last frame plus the displacement and turn
        integrated since, with the UKF's position covariance. The heading is the filter's (taco+: the compass less
        its learnt bias), not the raw compass: on an autopilot that fuses our velocity, its direction must not echo
        the autopilot's own yaw."""
        dx, dy = self.pre.interval_displacement
        x = self.ukf.x
        theta = wrap_angle(float(x[2]) + wrap_angle(self.pre.theta - self.pre.interval_heading))
        sigma_v = math.sqrt(max(float(self.ukf.P[3, 3]), 0.0)) if len(x) > 3 else math.nan  # taco+'s speed error
        return Estimate(self.t, np.array([x[0] + dx, x[1] + dy]), theta, float(self.pre.speed),
                        self.ukf.P[:2, :2].copy(), self.terms.epsilon, self.t - self.last_fix_t, sigma_speed=sigma_v)

    @property
    def filter_sigma_h(self) -> float:
        """The filter's own horizontal 1-sigma, metres (sqrt of the largest eigenvalue of P's position block),
        before any calibration of the reported accuracy: what a new Localiser carrying this one on must start
        from."""
        return horizontal_sigma(self.ukf.P[:2, :2])

    def widen(self, s: float) -> None:
        """Add s^2 (m^2) to both position variances."""
        x, P = self.ukf.get_state()
        P[:2, :2] += s * s * np.eye(2)
        self.ukf.set_state(x, P)

    def _record_track(self, t: float) -> None:
        x, P = self.ukf.x, self.ukf.P
        self.track.append((t, float(x[0]), float(x[1]), float(x[2]), float(P[0, 0]), float(P[0, 1]), float(P[1, 1])))

    def smoothed(self) -> SmoothResult:
        """Run the Pose2 smoother over everything recorded (offline; requires record=True)."""
        if not self.record:
            raise RuntimeError("smoothing needs a Localiser built with record=True")
        inc = np.array(self._graph_inc).reshape(-1, 3)
        fixes = [self._graph_fixes[k] for k in sorted(self._graph_fixes)]
        return smooth(np.array(self._graph_x), inc, np.array(self._graph_sigma), fixes, self.p.smoother)


def make_localiser(params: LocaliserParams, t0: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0,
                   speed: float = 0.0, record: bool = True, heading_offset: float = 0.0) -> Localiser:
    """The Localiser for the estimator mode in `params` (paper when params.plus is None, else taco+)."""
    return Localiser(params, t0, x, y, heading, speed, record=record, heading_offset=heading_offset)
