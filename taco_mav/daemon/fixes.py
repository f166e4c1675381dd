"""The daemon's fix pipeline: Localiser query -> camera frame -> matcher worker -> results queue ->
`Localiser.add_fix`, with the event log of every answered query and the gate decision.

Threads: `poll` and `drain` run on the daemon loop thread (the only one that touches the Localiser); the
`MatchWorker` thread runs the frame fetch and `FixService.answer`; the camera grabs in its own thread. Times:
queries carry autopilot seconds; a companion-clock camera is mapped through the daemon's `ClockMap`.

    fixes = FixPipeline(profile=profile, options=options, clockmap=clockmap, stats=stats, status=status)
    fixes.open(events); ...; fixes.start()      # camera grabbing; the worker starts with the origin
    fixes.on_origin(origin)                     # FixService on the origin's UTM zone, worker thread
    fixes.drain(loc, generation, shadow); fixes.poll(loc, generation)   # every loop step
    fixes.stop(); ...; fixes.close()

Faults: every query that yields no fix is cancelled in the Localiser (so it can ask again) and counted in
`stats.fixes` by reason: a camera guard reason (no_frame, stale_frame, corrupt_frame, bad_shape, blank_frame,
frozen_frame), "matcher_error", "matcher_timeout" (a job running longer than `options.matcher_timeout_s` wall
seconds: the worker is abandoned and a fresh one started, at most `MAX_STUCK` stuck threads at a time, then
"matcher_hung"), "worker_busy", "no_camera", "no_matcher". Without fixes the UKF's covariance grows and the
daemon's Health degrades the fix type: nothing here extrapolates a fix.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import time
from collections import Counter, deque
from typing import TYPE_CHECKING, Callable, Protocol

import numpy as np

from taco_mav.camera.calibration import FrameRectifier
from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.horizon import HorizonCheck
from taco_mav.camera.sources import CameraSource, ClockDomain, FrameGuard, FreezeWatch, open_camera
from taco_mav.config import Profile
from taco_mav.core.localiser import Localiser
from taco_mav.core.types import FixQuery
from taco_mav.cvgl.base import GroundFrame, Matcher, TruthFn
from taco_mav.cvgl.registry import make_matcher, needs_true_pose
from taco_mav.daemon.eventlog import EventLog
from taco_mav.daemon.shadow import Shadow, twin_fix
from taco_mav.daemon.worker import FetchFn, MatchWorker, WorkResult
from taco_mav.errors import ConfigError
from taco_mav.mavlink import encoders
from taco_mav.mavlink.decoders import SimPose
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_NOTICE, SEV_WARNING
from taco_mav.mavlink.timesync import ClockMap

if TYPE_CHECKING:
    from taco_mav.cvgl.satellite import SatelliteMap
    from taco_mav.cvgl.service import FixService
    from taco_mav.daemon.options import DaemonOptions

log = logging.getLogger(__name__)

STALE_LOOK_S = 60.0  # sources are asked for frames this far from the capture time, so stale ones are told apart
MAX_STUCK = 2  # abandoned matcher threads still inside the matcher; beyond this no new worker is started

StatusFn = Callable[[int, str, str | None], None]
"""status(severity, text, key): STATUSTEXT to the autopilot, rate-limited by key (the daemon's `_status`)."""


class FixCounters(Protocol):
    """The daemon counters this pipeline updates: queries polled, and fix outcomes by reason."""

    queries: int
    fixes: Counter[str]


class FixPipeline:
    """Camera, satellite map, matcher and matcher worker of one daemon run. profile: the matcher and map
    settings; options: camera spec, map path, frame_max_gap_s (s), matcher_latency_s (s); clockmap: companion
    -> autopilot clock; stats: counters updated in place; status: STATUSTEXT sender; matcher: use this
    matcher instead of the profile's (tests, embedding); truth: the simulator's true pose, for building a matcher
    that answers from it (`Matcher.needs_true_pose`; such a matcher needs neither camera nor map)."""

    def __init__(self, *, profile: Profile, options: DaemonOptions, clockmap: ClockMap, stats: FixCounters,
                 status: StatusFn, matcher: Matcher | None = None, truth: TruthFn | None = None) -> None:
        self.profile, self.opt = profile, options
        self.clockmap, self.stats, self.status = clockmap, stats, status
        self.truth = truth
        self.needs_true_pose = needs_true_pose(profile, matcher)
        self.ground_camera = GroundCamera.from_config(profile.camera)
        self.rectifier = FrameRectifier.from_config(profile.camera)  # raw frames -> the undistorted model
        self.events: EventLog | None = None
        self.camera: CameraSource | None = None
        self.guard: FrameGuard | None = None
        self.sat_map: SatelliteMap | None = None
        self.matcher: Matcher | None = matcher
        self.service: FixService | None = None
        self.worker: MatchWorker | None = None
        self._results: queue.Queue[WorkResult] = queue.Queue()  # shared by replacement workers
        self._held: deque[WorkResult] = deque()  # answers waiting out matcher_latency_s (autopilot time)
        self._stuck: list[MatchWorker] = []  # abandoned workers (matcher hung)
        self.last_weight = 0.0  # best crop's match weight w of the last answered query (0: none yet)

    # ------------------------------------------------------------------ lifecycle
    def open(self, events: EventLog) -> None:
        """Open the camera, the satellite map (`--map`, or the world's mosaic) and the matcher; no threads."""
        p, opt = self.profile, self.opt
        self.events = events
        self.camera = open_camera(opt.camera, self.ground_camera, self.rectifier.lens) if opt.camera else None
        if self.camera is not None:
            self.guard = FrameGuard(self.ground_camera.width, self.ground_camera.height, opt.frame_max_gap_s,
                                    check_frozen=not self.camera.noiseless, rectifier=self.rectifier,
                                    horizon=HorizonCheck(self.ground_camera), freeze=FreezeWatch())
        map_path = opt.map_path or getattr(self.camera, "mosaic_path", None)  # a simulated camera's world
        if map_path is not None:
            from taco_mav.cvgl.satellite import SatelliteMap

            self.sat_map = SatelliteMap(map_path, min_valid=p.map.min_valid_fraction,
                                        in_memory_max_mb=p.map.in_memory_max_mb)
        if self.needs_true_pose:
            log.warning("matcher %r draws fixes from the simulator's true pose: simulation only", p.matcher)
        if self.matcher is None and (self.needs_true_pose or self.sat_map is not None):
            self.matcher = make_matcher(p, truth=self.truth)
        else:
            log.warning("no satellite map (--map): no CVGL fixes, dead reckoning only")
        if self.matcher is not None and self.camera is None and not self.needs_true_pose:
            log.warning("no camera (--camera): no CVGL fixes, dead reckoning only")

    def start(self) -> None:
        """Start the camera's grab thread (the matcher worker starts with the origin, `on_origin`)."""
        if self.camera is not None:
            self.camera.start()
            try:
                assert self.guard is not None
                self.guard.check_source(self.camera, f"--camera {self.opt.camera}")
            except ConfigError:
                self.camera.close()
                raise

    def stop(self) -> None:
        """Stop the worker thread (waiting at most 1 s: a hung matcher never blocks shutdown) and close the
        camera; a failure is logged and the other still stops."""
        for name in ("worker", "camera"):
            obj = getattr(self, name, None)
            if obj is not None:
                try:
                    obj.stop() if name == "worker" else obj.close()
                except Exception:  # noqa: BLE001 - shutdown continues whatever failed
                    log.exception("stopping %s", name)

    @property
    def stuck(self) -> int:
        """Abandoned matcher threads still inside the matcher."""
        return sum(w.alive for w in self._stuck)

    def close(self) -> None:
        """Close the satellite map."""
        if self.sat_map is not None:
            self.sat_map.close()

    # ------------------------------------------------------------------ inputs
    def on_origin(self, origin: encoders.Origin) -> None:
        """The origin is known: a FixService on its UTM grid and the matcher worker thread (with a matcher)."""
        self.service = None
        if self.matcher is not None:
            from taco_mav.cvgl.service import profile_service

            self.service = profile_service(self.matcher, self.sat_map, origin.utm, self.profile)
            if self.worker is not None:
                self.worker.stop(0.0)
            self._new_worker()

    def _new_worker(self) -> None:
        self.worker = MatchWorker(self.service, self._results)
        self.worker.start()

    def on_pose(self, t: float, pose: SimPose) -> None:
        """The simulator's true pose at autopilot time t (s): to a camera that renders from it (`needs_pose`)."""
        if self.camera is not None and self.camera.needs_pose:
            self.camera.feed_pose(t, pose.lat, pose.lon, pose.yaw)  # type: ignore[attr-defined]

    # ------------------------------------------------------------------ queries and fixes
    def poll(self, loc: Localiser | None, generation: int, twin: Localiser | None = None) -> None:
        """Hand the Localiser's pending query (if any) to the worker, or cancel it when it cannot be answered.
        generation: the Localiser's generation, carried back with the result; twin: shadow mode's GNSS-free
        twin, which takes the same query (`adopt_query`) and so the same answer."""
        for w in self.guard.take_warnings() if self.guard is not None else []:
            assert self.events is not None
            self.events.write("camera_pitch", **dataclasses.asdict(w))
            self.status(SEV_WARNING, w.text, "camera_pitch")
        if loc is None:
            return
        self._watchdog(loc)
        q = loc.poll_query()
        if q is None:
            return
        self.stats.queries += 1
        fetch = self._frame_fetcher(q)
        if self.worker is None or fetch is None:
            loc.cancel_query(q.query_id)
            reason = "no_camera" if fetch is None else "matcher_hung" if self.service is not None else "no_matcher"
            self.stats.fixes[reason] += 1
            return
        if not self.worker.submit(q, fetch, generation):
            loc.cancel_query(q.query_id)
            self.stats.fixes["worker_busy"] += 1
        elif twin is not None:
            twin.adopt_query(q)

    def _watchdog(self, loc: Localiser) -> None:
        """Cancel a query the matcher has been on for longer than matcher_timeout_s (wall), abandon that
        worker and start a fresh one (unless MAX_STUCK abandoned ones are still stuck)."""
        self._stuck = [w for w in self._stuck if w.alive]
        w = self.worker
        job = w.running() if w is not None else None
        if w is None and self.service is not None and len(self._stuck) < MAX_STUCK:
            self._new_worker()  # a stuck thread came back: fixes resume
            return
        if w is None or job is None or time.monotonic() - job.started <= self.opt.matcher_timeout_s:
            return
        loc.cancel_query(job.query.query_id)
        self.stats.fixes["matcher_timeout"] += 1
        for q, _ in w.drop_waiting():
            loc.cancel_query(q.query_id)
            self.stats.fixes["worker_busy"] += 1
        w.abandon()
        self._stuck.append(w)
        text = f"matcher timeout ({self.opt.matcher_timeout_s:.1f}s) on query {job.query.query_id}"
        log.warning("%s; %d stuck matcher thread(s)", text, len(self._stuck))
        assert self.events is not None
        self.events.write("matcher_timeout", query_id=job.query.query_id, capture_t=job.query.capture_t,
                          stuck=len(self._stuck))
        self.status(SEV_WARNING, text, "matcher_timeout")
        self.worker = None
        if len(self._stuck) < MAX_STUCK:
            self._new_worker()

    def _frame_fetcher(self, q: FixQuery) -> FetchFn | None:
        """A callable the worker runs to get the frame nearest the capture time (rendering happens there);
        the frame guard vets it (FrameRejected with the reason). Without a camera, a matcher that answers from
        the true pose gets an empty frame at the capture time; any other gets none."""
        if self.camera is None:
            if not self.needs_true_pose:
                return None
            return lambda: GroundFrame(np.zeros((0, 0, 3), np.uint8), q.capture_t, self.ground_camera)
        return self.frame_fetcher(q.capture_t)

    def frame_fetcher(self, capture_t: float, guard: FrameGuard | None = None) -> FetchFn | None:
        """A callable (run in a worker thread) that returns the camera's frame nearest autopilot time `capture_t`
        (s) as a GroundFrame on the autopilot clock, vetted by `guard` (default the fix pipeline's; another user
        of the camera keeps its own, so its frames do not look frozen to it; a grey guard's frames are grey);
        None without a camera or, for a companion-clock camera, before the clocks are mapped."""
        cam, gap = self.camera, self.opt.frame_max_gap_s
        if cam is None:
            return None
        guard = guard or self.guard
        assert guard is not None
        if cam.clock is ClockDomain.AUTOPILOT:
            t_src, back = capture_t, 0.0
        else:
            off = self.clockmap.offset
            if off is None:
                return None
            t_src, back = capture_t - off, off

        def fetch() -> GroundFrame:
            t_frame, image = guard.check(cam.frame_near(t_src, max(gap, STALE_LOOK_S), guard.grey), t_src)
            return GroundFrame(image, t_frame + back, self.ground_camera)

        return fetch

    def _due(self, now: float, generation: int) -> list[WorkResult]:
        """Finished answers due at autopilot time `now` (s): all of them, or with `matcher_latency_s` those
        whose capture time is at least that long ago (the rest stay held, in order). Answers of an older
        `generation` are due at once (dropped by the caller): after a reboot their capture times are on the
        old clock and would otherwise hold back every later answer."""
        while True:
            try:
                self._held.append(self._results.get_nowait())
            except queue.Empty:
                break
        lag = self.opt.matcher_latency_s
        due = []
        while self._held and (lag <= 0 or self._held[0].generation != generation
                              or now >= self._held[0].query.capture_t + lag):
            due.append(self._held.popleft())
        return due

    def drain(self, loc: Localiser | None, generation: int, shadow: Shadow | None = None) -> None:
        """Apply finished results (not an older generation's) to the Localiser and the shadow; event, STATUSTEXT."""
        twin = shadow.twin if shadow is not None else None
        if loc is None:
            return
        assert self.events is not None
        for t, kind, detail in loc.take_lock_events():
            self.events.write("lock", t=t, kind=kind, detail=detail)
            self.status(SEV_WARNING if kind in ("lock_lost", "relock_failed", "imu_disagrees", "fixes_disagree",
                                                       "camera_refuted")
                        else SEV_INFO, f"{kind.replace('_', ' ')} {detail}".strip(), None)
        for res in self._due(loc.t, generation):
            q = res.query
            if res.generation != generation:
                self.stats.fixes["stale_generation"] += 1
                continue
            if res.results is None:
                loc.cancel_query(q.query_id)
                if twin is not None:
                    twin.cancel_query(q.query_id)
                self.stats.fixes[res.error or "error"] += 1
                self.events.write("fix", query_id=q.query_id, capture_t=q.capture_t, error=res.error,
                                  detail=res.detail)
                self.status(SEV_NOTICE, f"no fix: {res.error}", "fix_error")
                continue
            try:
                out = loc.add_fix(q.query_id, res.results)
            except Exception:  # noqa: BLE001 - a malformed answer must not stop the loop
                log.exception("add_fix failed on query %d", q.query_id)
                loc.cancel_query(q.query_id)
                self.stats.fixes["fix_error"] += 1
                continue
            self.stats.fixes[out.reason] += 1
            if twin is not None:
                self.stats.fixes[f"shadow_{twin_fix(twin, q.query_id, res.results, shadow)}"] += 1
            self.last_weight = max(out.weights, default=0.0)  # the ground station's taco_w (gcs.py)
            est = loc.estimate()
            self.events.write(
                "fix", query_id=q.query_id, reason=q.reason, capture_t=q.capture_t, frame_t=res.frame_t,
                arrival_t=out.arrival_t, epsilon=q.epsilon, heading=q.heading, centre=q.centre,
                crop_centres=q.crop_centres,
                results=[None if r is None else {"R": r.R, "t": r.t, "w": r.w, "null_w": r.null_w}
                         for r in res.results],
                accepted=out.accepted, gate=out.reason, chosen=out.chosen, xy=out.xy, yaw_residual=out.yaw_residual,
                sigma_fwd=out.sigma_fwd, sigma_lat=out.sigma_lat, nis=out.nis, matcher_s=res.elapsed_s,
                estimate_xy=est.xy, sigma_h=est.sigma_h)
            if out.accepted:
                self.status(SEV_INFO, f"fix accepted w={max(out.weights):.2f} sig {est.sigma_h:.1f}m", "fix")
            else:
                self.status(SEV_NOTICE, f"fix rejected: {out.reason}", "fix")
