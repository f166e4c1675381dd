"""The Localiser: the TACO pipeline (paper Fig. 2) as one object that the offline evaluator and the live daemon both
drive, in either estimator mode.

    loc = Localiser(params, t0, heading=..., speed=...)
    loc.add_imu(sample)            # any rate, irregular dt; frame-rate UKF predict inside
    q = loc.poll_query()           # a FixQuery when the trigger fired (capture time, centre, 5 crop centres)
    loc.add_fix(q.query_id, five)  # the matcher's five MatchResults, possibly late: rewind, update, replay
    loc.estimate()                 # Estimate(t, xy, theta, speed, cov_xy, ...)
    loc.smoothed()                 # Pose2 smoother over the whole run (offline)

The Localiser composes its parts and owns nothing else: the `timeline` (the preintegrator, the UKF, the frame
history and every correction's rewind and replay), the `desk` (the query in flight), the real-GNSS fusion
(`gnss`), the offline `record`, and the `estimator` (estimator.py): what differs between the paper's method
(paper.py, when params.plus is None) and taco+ (plus/estimator.py), as parts chosen from the parameters: the
filter, the trigger, the fix policy, the GNSS update, the reported accuracy and the aiding (stops, the camera's
speed, the drive command, the safety guard, the lock), the last two taco+'s only.

World frame: ENU metres relative to the origin (the start-up GNSS reading); heading ENU radians; autopilot s.
"""

from __future__ import annotations

from typing import Sequence

from taco_mav.core.frames import FixOutcome
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.estimator import EstimatorParts
from taco_mav.core.paper import make_paper
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.estimator import make_plus
from taco_mav.core.queries import Answering, QueryDesk
from taco_mav.core.run_record import RunRecord
from taco_mav.core.search import search_centres
from taco_mav.core.smoother import SmoothResult
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import Estimate, FixQuery, GnssFix, GnssOutcome, ImuSample, MatchResult


class Localiser:
    """The TACO pipeline in paper mode or taco+ (`estimator`), plus real GNSS while it is honest (`add_gnss`). All
    times in autopilot seconds."""

    def __init__(self, params: LocaliserParams, t0: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0,
                 speed: float = 0.0, record: bool = True, heading_offset: float = 0.0) -> None:
        """t0: start time, s; (x, y): start position, ENU metres; heading: ENU grid heading, rad; speed: m/s
        (from the start-up GNSS reading); heading_offset: UTM meridian convergence, rad, added to every compass
        heading; record: keep the online track, outcomes and smoother inputs (offline evaluation)."""
        self.p = params
        self.record = RunRecord(x, y, heading) if record else None
        self.timeline = Timeline(params, t0, x, y, heading, speed, heading_offset, self.record)
        self.desk = QueryDesk(t0, params.trigger.query_timeout_s, params.latency.apply_on_arrival, self.record)
        self.gnss = GnssFusion(self.timeline, params.gnss)
        self.estimator: EstimatorParts = (make_paper(self.timeline, self.desk, params) if params.plus is None
                                     else make_plus(self.timeline, self.desk, self.gnss, params, params.plus))
        self.gnss.serve(self.estimator.gnss, self.estimator.aids)
        self.timeline.start(self.estimator.filter.make_ukf(x, y, heading), self.estimator.filter.predict)
        self.aids = self.estimator.aids
        self.takes_ground_motion = self.aids is not None  # add_ground_motion is used (a speed measurement)
        if self.record is not None and self.aids is not None:
            self.record.lock_events = self.aids.lock_events

    @property
    def t(self) -> float:
        """The IMU clock: the time of the last integrated sample, autopilot s."""
        return self.timeline.t

    # ------------------------------------------------------------------ the IMU path
    def add_imu(self, sample: ImuSample) -> None:
        """Integrate one IMU sample (FRD specific force, gyro, NED attitude); at each frame boundary run the
        UKF predict on the accumulated increment and evaluate the trigger."""
        tl, aids = self.timeline, self.aids
        fresh = sample.t > tl.pre.t
        if fresh and aids is not None:
            aids.before_imu()
        dt, due = tl.integrate(sample)
        if dt > 0.0:
            self.gnss.on_imu(tl.t, dt)
        if due:
            self._frame()
        if fresh and aids is not None:
            aids.after_imu(sample)

    def _frame(self) -> None:
        tl, aids = self.timeline, self.aids
        tick = tl.open_frame()
        if aids is not None:
            aids.open_frame(tick)
        tl.advance_new(tick)
        if aids is not None:
            aids.close_frame(tick)
        if self.record is not None:
            self.record.frame(tick, self.estimator.filter.odometry_sigma(tick), tl.ukf)
        self.gnss.on_frame(tick)
        self._maybe_trigger()

    def _maybe_trigger(self) -> None:
        tl = self.timeline
        if not self.desk.free(tl.t):
            return
        plan = self.gnss.plan(self.estimator.trigger.plan())
        if plan is None:
            return
        reason, bias, offsets = plan
        theta = float(tl.pre.theta)
        centre, crops = search_centres(tl.ukf.fix_prediction()[0], theta, bias, offsets)  # in the map
        self.desk.issue(capture_t=tl.t, centre=centre, heading=theta, offsets_body=offsets, crop_centres=crops,
                           epsilon=tl.terms.epsilon, reason=reason)

    # ------------------------------------------------------------------ queries and answers
    def poll_query(self) -> FixQuery | None:
        """The query the trigger produced, once (None when there is none). At most one is in flight."""
        return self.desk.poll(self.timeline.t)

    def adopt_query(self, q: FixQuery) -> None:
        """Take another Localiser's query as this one's in flight, so that its answer (`add_fix`) updates this
        filter too: a shadow twin (the daemon's `--shadow`) fed the same camera fixes as the filter it runs beside.
        The answer is applied to this filter's own state, at the query's capture time."""
        self.desk.adopt(q, self.timeline.t)

    def cancel_query(self, query_id: int) -> None:
        """Give up on an in-flight query (matcher failed); the time counter is not reset."""
        self.desk.cancel(query_id)

    def add_fix(self, query_id: int, results: Sequence[MatchResult | None]) -> FixOutcome:
        """Hand back the matcher's results for a query (same order as its crop centres; None for a crop that
        could not be matched, e.g. off the map). What an answer does is the estimator's (paper: the best candidate
        behind the yaw gate; taco+: consensus, gates and lock); it is applied at its capture time (rewind,
        update, replay) unless params.latency.apply_on_arrival."""
        answer = self.desk.take(query_id, results, self.timeline.t)
        if isinstance(answer, Answering):
            out = self.estimator.fixes.judge(answer, results)
        else:
            out = answer
            if self.aids is not None:
                self.aids.answer_missing(out)
        if self.record is not None:
            self.record.outcomes.append(out)
        self.gnss.on_fix_outcome(out)
        return out

    # ------------------------------------------------------------------ other inputs
    def add_ground_motion(self, t0: float, t1: float, d_fwd: float, d_left: float, sigma_m: float) -> str:
        """The camera's ground-plane motion between t0 and t1 (autopilot s; metres in frame 0's body axes) as a
        speed measurement (taco+; see plus/camera_speed.py); paper mode has no speed state: "ignored"."""
        return "ignored" if self.aids is None else self.aids.add_ground_motion(t0, t1, d_fwd, d_left, sigma_m)

    def set_drive_command(self, t: float, driving: bool) -> None:
        """Whether the autopilot drives at autopilot time t (s): taco+ vetoes its zero-velocity updates while it
        does; paper mode ignores it."""
        if self.aids is not None:
            self.aids.set_drive_command(t, driving)

    def add_gnss(self, fix: GnssFix) -> GnssOutcome:
        """One real GNSS reading (see gnss/fusion.py); taco+ also checks its ground speed against the camera's."""
        out = self.gnss.add(fix)
        if self.aids is not None:
            self.aids.after_gnss(fix, out)
        return out

    def take_lock_events(self) -> list[tuple[float, str, str]]:
        """Lock events not yet taken, (t s, kind, detail) each (taco+: lock_lost / relocalised / relock_failed /
        recovered ...; the daemon logs each once); paper mode keeps no lock."""
        return [] if self.aids is None else self.aids.take_lock_events()

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> Estimate:
        """The current estimate: the filter's own (`Timeline.estimate`) with taco+'s reported accuracy (the fixes'
        variance factor, floors) and its state in `extra`; while a receiver is fused, at least
        what the last camera check saw of its error (`GnssFusion.report`)."""
        tl = self.timeline
        est = tl.estimate(tl.t - self.desk.answered_t)
        if self.estimator.report is not None:
            est = self.estimator.report.report(est)
        return self.gnss.report(est)

    def smoothed(self) -> SmoothResult:
        """Run the Pose2 smoother over everything recorded (offline; requires record=True)."""
        if self.record is None:
            raise RuntimeError("smoothing needs a Localiser built with record=True")
        return self.record.smoothed(self.p.smoother)


def make_localiser(params: LocaliserParams, t0: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0,
                   speed: float = 0.0, record: bool = True, heading_offset: float = 0.0) -> Localiser:
    """The Localiser for the estimator mode in `params` (paper when params.plus is None, else taco+)."""
    return Localiser(params, t0, x, y, heading, speed, record=record, heading_offset=heading_offset)
