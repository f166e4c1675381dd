"""The filter's timeline: the one owner of the estimator's state over time. It holds the preintegrator, the UKF,
the bounded history of processed frames (`Tick`) and the error model's anchor window, closes a frame at each
frame slot, and applies every correction (corrections.py) through one path: on arrival, or at its frame with a
rewind to that frame and a replay of the frames after it, which applies their own corrections again. Nothing
else writes the UKF's state or the preintegrator's position.

World frame ENU metres relative to the origin; headings ENU radians; times autopilot seconds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np

from taco_mav.core.corrections import Correction, HeadingFix, PositionFix
from taco_mav.core.error_model import AnchorWindow, ErrorTerms, HighPass, MomentAccumulator, error_terms
from taco_mav.core.frames import Tick
from taco_mav.core.params import LocaliserParams
from taco_mav.core.preintegration import Preintegrator, wrap_angle
from taco_mav.core.run_record import RunRecord
from taco_mav.core.types import Estimate, ImuSample, horizontal_sigma
from taco_mav.core.ukf import PlanarUkf, fix_covariance

__all__ = ["Timeline"]

Predict = Callable[[PlanarUkf, Tick, ErrorTerms], None]  # the estimator's UKF predict over one frame


class Timeline:
    """The preintegrator, the UKF and the frames a late correction rewinds to (see the module docstring). The
    estimator's noise model supplies the UKF (`start`) and its predict; `record` keeps the offline records."""

    def __init__(self, params: LocaliserParams, t0: float, x: float, y: float, heading: float, speed: float,
                 heading_offset: float, record: RunRecord | None) -> None:
        """t0: start time, s; (x, y): start position, ENU m; heading: ENU grid heading, rad; speed: m/s;
        heading_offset: UTM meridian convergence, rad, added to every compass heading."""
        self.p = params
        self.frame_dt = 1.0 / params.imu.frame_rate_hz
        self.pre = Preintegrator.from_params(params.imu, t0, x, y, heading, speed, heading_offset)
        self.record = record
        self.t = t0
        self.terms = ErrorTerms(0.0, 0.0, 0.0)  # the error model's terms at the last frame (m)
        self._highpass = HighPass(params.imu.accel_highpass_hz)
        self._interval_residual = MomentAccumulator()
        self._next_tick = t0 + self.frame_dt
        self._window = AnchorWindow()
        frames = int(math.ceil(params.latency.history_s * params.imu.frame_rate_hz))
        self.history: deque[Tick] = deque(maxlen=max(2, frames + 2))  # oldest first
        self._nodes = 0
        self.ukf: PlanarUkf
        self._predict: Predict

    def start(self, ukf: PlanarUkf, predict: Predict) -> None:
        """The estimator's filter at the start pose and its predict over one frame."""
        self.ukf, self._predict = ukf, predict
        if self.record is not None:
            self.record.track_state(self.t, ukf)

    # ------------------------------------------------------------------ the IMU and the frames
    def integrate(self, sample: ImuSample) -> tuple[float, bool]:
        """Integrate one IMU sample: the time it advanced the clock by, s (0 for an old or repeated sample), and
        whether a frame slot is due (then `open_frame`, `advance_new`)."""
        dt = self.pre.add(sample)
        if dt <= 0.0:
            return dt, False
        self.t = sample.t
        self._interval_residual.add(self._highpass.step(self.pre.accel_fwd, dt))
        # A frame closes at the sample nearest its slot (within half a sample interval, at most a quarter period),
        # so timestamp jitter (KITTI's 10 Hz OXTS wanders by ~+-10 ms) neither skips nor doubles frames.
        tol = min(0.25 * self.frame_dt, 0.5 * dt)
        if self.t < self._next_tick - tol:
            return dt, False
        while self._next_tick <= self.t + tol:
            self._next_tick += self.frame_dt
        return dt, True

    def open_frame(self) -> Tick:
        """The next frame: the increment integrated since the last one and its high-passed residual."""
        theta_start = self.pre.interval_heading
        inc = self.pre.take_increment()
        return Tick(self._nodes + 1, self.t, inc, self._interval_residual.take(), theta_start)

    def advance_new(self, tick: Tick) -> None:
        """Predict and update a new frame from the current state and keep it in the history."""
        self._advance(tick, self.pre.x, self.pre.y)
        self._nodes += 1
        self.history.append(tick)

    def _advance(self, tick: Tick, pre_x: float, pre_y: float) -> None:
        """Predict, the compass update and the frame's corrections, from the current UKF state and anchor window."""
        inc = tick.inc
        self._window = self._window.extend(inc.dt, inc.distance, tick.residual)
        d_div = math.hypot(self.ukf.x[0] - pre_x, self.ukf.x[1] - pre_y)
        em = self.p.error_model
        terms = error_terms(self._window, d_div, self.p.imu.gyro_arw, em.cross_k, em.along_k, em.divergence_k)
        self._predict(self.ukf, tick, terms)
        self.ukf.update_heading(inc.theta_end, self.p.ukf.compass_sigma_rad)
        settles = False
        for c in tick.corrections:
            c.apply(self.ukf, tick)
            settles = settles or c.settles
        self.terms = terms
        tick.terms, tick.window, tick.pre_xy = terms, self._window, (pre_x, pre_y)
        tick.x, tick.P = self.ukf.get_state()
        if settles:
            self._reset_anchor()
            tick.window = self._window

    # ------------------------------------------------------------------ corrections
    def capture_tick(self, capture_t: float) -> Tick | None:
        """The history frame a correction captured at `capture_t` (s) applies at: the latest with
        latency.apply_on_arrival, else the frame closed at that time (None once it left the history)."""
        if self.p.latency.apply_on_arrival:
            return self.history[-1] if self.history else None
        return next((h for h in self.history if abs(h.t - capture_t) < 1e-6), None)

    def fix(self, tick: Tick | None, xy: np.ndarray, s_f: float, s_l: float,
            heading: tuple[float, float] | None = None) -> float:
        """A camera fix (ENU m; body-frame 1-sigmas forward and lateral, m; taco+: the true heading it measures,
        (ENU rad, 1-sigma rad)) applied at its capture frame `tick` (`capture_tick`) and kept for the smoother;
        returns its NIS."""
        theta = float(self.ukf.x[2]) if self.p.latency.apply_on_arrival else float(tick.x[2])  # type: ignore[union-attr]
        fixes: list[Correction] = [PositionFix(xy.copy(), fix_covariance(theta, s_f, s_l))]
        if heading is not None:
            fixes.append(HeadingFix(*heading))
        nis = self.correct(tick, *fixes)
        if self.record is not None and tick is not None:
            self.record.fix(tick, xy, s_f, s_l)
        return nis

    def correct(self, tick: Tick | None, *corrections: Correction) -> float:
        """Apply `corrections` at frame `tick`: with latency.apply_on_arrival to the current state (kept on the
        frame, which is the latest), else rewound to `tick` (required), kept there and replayed forward. The
        anchor window restarts at the frame. Returns the first correction's NIS."""
        if self.p.latency.apply_on_arrival:
            nis = [c.apply(self.ukf, tick) for c in corrections]  # type: ignore[arg-type]
            if tick is not None:
                for c in corrections:
                    tick.add(c)
                tick.x, tick.P = self.ukf.get_state()
            self._reset_anchor()
            dx, dy = self.pre.interval_displacement
            self.pre.reset_position(float(self.ukf.x[0]) + dx, float(self.ukf.x[1]) + dy)
            if self.record is not None and tick is not None:
                self.record.restate([tick])
            return nis[0]
        assert tick is not None
        self.ukf.set_state(tick.x, tick.P)
        nis = [c.apply(self.ukf, tick) for c in corrections]
        for c in corrections:
            tick.add(c)
        tick.x, tick.P = self.ukf.get_state()
        self._reset_anchor()  # the replay below re-extends the window and recomputes the terms
        pre_x, pre_y = float(tick.x[0]), float(tick.x[1])
        tick.window, tick.pre_xy = self._window, (pre_x, pre_y)
        later = [h for h in self.history if h.t > tick.t]
        pre_x, pre_y = self._replay(later, pre_x, pre_y)
        dx, dy = self.pre.interval_displacement
        self.pre.reset_position(pre_x + dx, pre_y + dy)
        if self.record is not None:
            self.record.restate([tick, *later])
        return nis[0]

    def correct_batch(self, base: Tick, batch: list[tuple[Tick, Correction]]) -> None:
        """Keep each (frame, correction) of `batch` on its frame and apply them all in one rewind to `base` (the
        earliest of their frames) and one replay; the anchor window restarts at `base`."""
        for h, c in batch:
            h.add(c)
        self.ukf.set_state(base.x, base.P)
        for c in (c for h, c in batch if h is base):
            c.apply(self.ukf, base)
        self._settle(base)
        self.replay_from(base)

    def forget(self, base: Tick, keep: Callable[[Tick], None]) -> bool:
        """Let `keep` drop corrections from the frames after `base`, then rewind to `base` and replay without
        them; False (nothing done) when none was dropped."""
        later = [h for h in self.history if h.t > base.t]
        before = [len(h.corrections) for h in later]
        for h in later:
            keep(h)
        if [len(h.corrections) for h in later] == before:
            return False
        self.ukf.set_state(base.x, base.P)
        self.replay_from(base)
        return True

    def replay_from(self, base: Tick) -> None:
        """Replay the frames after `base` from the filter's current state (which is base's)."""
        self._reset_anchor()
        pre_x, pre_y = float(self.ukf.x[0]), float(self.ukf.x[1])
        base.window, base.pre_xy = self._window, (pre_x, pre_y)
        later = [h for h in self.history if h.t > base.t]
        self._replay(later, pre_x, pre_y)
        dx, dy = self.pre.interval_displacement
        self.pre.reset_position(float(self.ukf.x[0]) + dx, float(self.ukf.x[1]) + dy)
        if self.record is not None:
            self.record.restate([base, *later])

    def _settle(self, tick: Tick) -> None:
        """After updates at `tick` outside a frame's advance: keep the state on it and restart the anchor window."""
        tick.x, tick.P = self.ukf.get_state()
        self._reset_anchor()
        tick.window = self._window

    def _replay(self, later: list[Tick], pre_x: float, pre_y: float) -> tuple[float, float]:
        """Advance the history frames `later` again from the filter's current state, the dead-reckoned position
        carried from (pre_x, pre_y) ENU m along their increments; returns where it ends."""
        for h in later:
            c, s = math.cos(h.theta_start), math.sin(h.theta_start)
            pre_x += c * h.inc.d_fwd - s * h.inc.d_left
            pre_y += s * h.inc.d_fwd + c * h.inc.d_left
            self._advance(h, pre_x, pre_y)
        return pre_x, pre_y

    def _reset_anchor(self) -> None:
        self._window = AnchorWindow()
        self.terms = ErrorTerms(0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ the present state
    def adjust(self, x: np.ndarray, P: np.ndarray, keep: bool = False) -> None:
        """Set the filter's present state (a covariance inflated, a state fed back); keep: also on the latest
        frame, so a rewind to it starts from the adjusted state."""
        self.ukf.set_state(x, P)
        if keep and self.history:
            self.history[-1].x, self.history[-1].P = self.ukf.get_state()

    def widen(self, s: float) -> None:
        """Add s^2 (m^2) to both position variances of the present state."""
        x, P = self.ukf.get_state()
        P[:2, :2] += s * s * np.eye(2)
        self.ukf.set_state(x, P)

    def estimate(self, since_fix_s: float) -> Estimate:
        """The filter's own estimate: UKF position and heading at the last frame plus the displacement and turn
        integrated since, with the UKF's position covariance. The heading is the filter's (taco+: the compass less
        its learnt bias), not the raw compass: on an autopilot that fuses our velocity, its direction must not echo
        the autopilot's own yaw. since_fix_s: seconds since the last answered query."""
        dx, dy = self.pre.interval_displacement
        x = self.ukf.x
        theta = wrap_angle(float(x[2]) + wrap_angle(self.pre.theta - self.pre.interval_heading))
        sigma_v = math.sqrt(max(float(self.ukf.P[3, 3]), 0.0)) if len(x) > 3 else math.nan  # taco+'s speed error
        return Estimate(self.t, np.array([x[0] + dx, x[1] + dy]), theta, float(self.pre.speed),
                        self.ukf.P[:2, :2].copy(), self.terms.epsilon, since_fix_s, sigma_speed=sigma_v,
                        filter_sigma_h=horizontal_sigma(self.ukf.P[:2, :2]))
