"""The daemon's fix pipeline: Localiser query -> camera frame -> matcher worker -> results queue ->
`Localiser.add_fix`, with the event log of every answered query and the gate decision.

Threads: `poll` and `drain` run on the daemon loop thread (the only one that touches the Localiser); the
`MatchWorker` thread runs the frame fetch and `FixService.answer`; the camera grabs in its own thread. Times:
queries carry autopilot seconds; a companion-clock camera is mapped through the daemon's `ClockMap`.

    fixes = FixPipeline(profile, options, clockmap, stats, status)
    fixes.open(events); ...; fixes.start()      # camera grabbing; the worker starts with the origin
    fixes.on_origin(origin)                     # FixService on the origin's UTM zone, worker thread
    fixes.drain(loc, generation); fixes.poll(loc, generation)   # every loop step
    fixes.stop(); ...; fixes.close()
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from typing import TYPE_CHECKING, Any, Callable, Protocol

import numpy as np

from taco_mav.camera import CameraSource, ClockDomain, WorldSource, open_camera
from taco_mav.camera_geometry import GroundCamera
from taco_mav.config import Profile
from taco_mav.core.localiser import Localiser
from taco_mav.core.types import FixQuery
from taco_mav.cvgl.base import GroundFrame
from taco_mav.link import encoders
from taco_mav.link.decoders import SimPose
from taco_mav.link.eventlog import EventLog
from taco_mav.link.timesync import ClockMap
from taco_mav.link.worker import MatchWorker, WorkResult

if TYPE_CHECKING:
    from taco_mav.link.daemon import DaemonOptions

log = logging.getLogger(__name__)

SEV_NOTICE, SEV_INFO = 5, 6  # MAV_SEVERITY of the fix STATUSTEXTs (same values as taco_mav.link.daemon)

StatusFn = Callable[[int, str, str | None], None]
"""status(severity, text, key): STATUSTEXT to the autopilot, rate-limited by key (the daemon's `_status`)."""


class FixCounters(Protocol):
    """The daemon counters this pipeline updates: queries polled, and fix outcomes by reason."""

    queries: int
    fixes: Counter[str]


class FixPipeline:
    """Camera, satellite map, matcher and matcher worker of one daemon run. profile: the matcher and map
    settings; options: camera spec, map path, frame_max_gap_s (s), matcher_latency_s (s); clockmap: companion
    -> autopilot clock; stats: counters updated in place; status: STATUSTEXT sender."""

    def __init__(self, profile: Profile, options: DaemonOptions, clockmap: ClockMap, stats: FixCounters,
                 status: StatusFn) -> None:
        self.profile, self.opt = profile, options
        self.clockmap, self.stats, self.status = clockmap, stats, status
        self.ground_camera = GroundCamera.from_config(profile.camera)
        self.events: EventLog | None = None
        self.camera: CameraSource | None = None
        self.sat_map: Any = None
        self.matcher: Any = None
        self.service: Any = None
        self.worker: MatchWorker | None = None
        self._truth: deque[tuple[float, float, float, float]] = deque(maxlen=3000)  # SIMSTATE: t, E, N, theta grid

    # ------------------------------------------------------------------ lifecycle
    def open(self, events: EventLog) -> None:
        """Open the camera, the satellite map (`--map`, or the world's mosaic) and the matcher; no threads."""
        p, opt = self.profile, self.opt
        self.events = events
        self.camera = open_camera(opt.camera, self.ground_camera) if opt.camera else None
        map_path = opt.map_path or (self.camera.mosaic_path if isinstance(self.camera, WorldSource) else None)
        if map_path is not None:
            from taco_mav.cvgl.satellite import SatelliteMap

            self.sat_map = SatelliteMap(map_path, min_valid=p.map.min_valid_fraction,
                                        in_memory_max_mb=p.map.in_memory_max_mb)
        if p.matcher == "emulator":
            log.warning("matcher 'emulator' draws fixes from the SIMSTATE true pose: simulation only")
        if p.matcher == "emulator" or self.sat_map is not None:
            from taco_mav.cvgl.registry import make_matcher

            self.matcher = make_matcher(p, truth=self._truth_at if p.matcher == "emulator" else None)
        else:
            log.warning("no satellite map (--map): no CVGL fixes, dead reckoning only")
        if self.matcher is not None and self.camera is None and p.matcher != "emulator":
            log.warning("no camera (--camera): no CVGL fixes, dead reckoning only")

    def start(self) -> None:
        """Start the camera's grab thread (the matcher worker starts with the origin, `on_origin`)."""
        if self.camera is not None:
            self.camera.start()

    def stop(self) -> None:
        """Stop the worker thread and close the camera; a failure is logged and the other still stops."""
        for name in ("worker", "camera"):
            obj = getattr(self, name, None)
            if obj is not None:
                try:
                    obj.stop() if name == "worker" else obj.close()
                except Exception:  # noqa: BLE001 - shutdown continues whatever failed
                    log.exception("stopping %s", name)

    def close(self) -> None:
        """Close the satellite map."""
        if self.sat_map is not None:
            self.sat_map.close()

    # ------------------------------------------------------------------ inputs
    def on_origin(self, origin: encoders.Origin) -> None:
        """The origin is known: a FixService on its UTM grid and the matcher worker thread (with a matcher)."""
        self.service = None
        if self.matcher is not None:
            from taco_mav.cvgl.service import FixService

            self.service = FixService(self.matcher, self.sat_map, origin.utm, self.profile.map.crop_size_px,
                                      self.profile.map.crop_m_per_px)
            self.worker = MatchWorker(self.service, self.opt.matcher_latency_s)
            self.worker.start()

    def on_pose(self, t: float, pose: SimPose, origin: encoders.Origin | None) -> None:
        """SIMSTATE true pose at autopilot time t (s): drives a world camera and the emulator's truth."""
        if isinstance(self.camera, WorldSource):
            self.camera.feed_pose(t, pose.lat, pose.lon, pose.yaw)
        if origin is not None:
            e, n = origin.projector.to_utm(pose.lat, pose.lon)
            theta = math.pi / 2 - pose.yaw + origin.convergence
            self._truth.append((t, float(e), float(n), math.remainder(theta, 2 * math.pi)))

    def clear_truth(self) -> None:
        """Forget the SIMSTATE poses (the autopilot clock restarted)."""
        self._truth.clear()

    def _truth_at(self, t: float) -> tuple[float, float, float]:
        """SIMSTATE pose nearest autopilot time t: absolute UTM E, N metres and grid heading (emulator only)."""
        if not self._truth:
            raise RuntimeError("no SIMSTATE received: the emulator matcher needs the simulator's true pose")
        best = min(self._truth, key=lambda s: abs(s[0] - t))
        return best[1], best[2], best[3]

    # ------------------------------------------------------------------ queries and fixes
    def poll(self, loc: Localiser | None, generation: int) -> None:
        """Hand the Localiser's pending query (if any) to the worker, or cancel it when it cannot be answered.
        generation: the Localiser's generation, carried back with the result."""
        if loc is None:
            return
        q = loc.poll_query()
        if q is None:
            return
        self.stats.queries += 1
        fetch = self._frame_fetcher(q)
        if self.worker is None or fetch is None:
            loc.cancel_query(q.query_id)
            self.stats.fixes["no_matcher" if self.worker is None else "no_camera"] += 1
            return
        if not self.worker.submit(q, fetch, generation):
            loc.cancel_query(q.query_id)
            self.stats.fixes["worker_busy"] += 1

    def _frame_fetcher(self, q: FixQuery) -> Callable[[], GroundFrame | None] | None:
        """A callable the worker runs to get the frame nearest the capture time (rendering happens there)."""
        cam, gap = self.camera, self.opt.frame_max_gap_s
        if cam is None:
            if self.profile.matcher != "emulator":
                return None
            return lambda: GroundFrame(np.zeros((0, 0, 3), np.uint8), q.capture_t, self.ground_camera)
        if cam.clock is ClockDomain.AUTOPILOT:
            t_src, back = q.capture_t, 0.0
        else:
            off = self.clockmap.offset
            if off is None:
                return None
            t_src, back = q.capture_t - off, off

        def fetch() -> GroundFrame | None:
            got = cam.frame_near(t_src, gap)
            return None if got is None else GroundFrame(got[1], got[0] + back, self.ground_camera)

        return fetch

    def drain(self, loc: Localiser | None, generation: int) -> None:
        """Apply every finished worker result to the Localiser (results of an older generation are dropped),
        log each as a "fix" event and report the gate decision by STATUSTEXT."""
        if self.worker is None or loc is None:
            return
        assert self.events is not None
        while not self.worker.out.empty():
            res: WorkResult = self.worker.out.get_nowait()
            q = res.query
            if res.generation != generation:
                self.stats.fixes["stale_generation"] += 1
                continue
            if res.results is None:
                loc.cancel_query(q.query_id)
                self.stats.fixes[res.error or "error"] += 1
                self.events.write("fix", query_id=q.query_id, capture_t=q.capture_t, error=res.error)
                continue
            out = loc.add_fix(q.query_id, res.results)
            self.stats.fixes[out.reason] += 1
            est = loc.estimate()
            self.events.write(
                "fix", query_id=q.query_id, reason=q.reason, capture_t=q.capture_t, frame_t=res.frame_t,
                arrival_t=out.arrival_t, epsilon=q.epsilon, heading=q.heading, centre=q.centre,
                crop_centres=q.crop_centres,
                results=[None if r is None else {"R": r.R, "t": r.t, "w": r.w} for r in res.results],
                accepted=out.accepted, gate=out.reason, chosen=out.chosen, xy=out.xy, yaw_residual=out.yaw_residual,
                sigma_fwd=out.sigma_fwd, sigma_lat=out.sigma_lat, nis=out.nis, matcher_s=res.elapsed_s,
                estimate_xy=est.xy, sigma_h=est.sigma_h)
            if out.accepted:
                self.status(SEV_INFO, f"fix accepted w={max(out.weights):.2f} sig {est.sigma_h:.1f}m", "fix")
            else:
                self.status(SEV_NOTICE, f"fix rejected: {out.reason}", "fix")
