"""The daemon's camera-speed pipeline: ground-plane motion between two camera frames a fraction of
a second apart (`cvgl.ground_motion.GroundMotion`) as a speed measurement for taco+.

Threads: `tick` runs on the daemon loop thread (it asks for a measurement every `interval_s` of autopilot time
and hands finished ones to the Localiser); one worker thread fetches the two frames (rendering a world camera
happens there), warps them and correlates. Times are autopilot seconds; the heading change between the two
frames comes from the Localiser's compass headings, recorded at every loop step (`on_heading`, ENU rad).

    motion = start_camera_speed(fixes)   # after fixes.open(): a started MotionPipeline, or None
    ...; motion.tick(loc) every loop step; ...; motion.stop()
"""

from __future__ import annotations

import logging
import math
import queue
import threading
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

from taco_mav.camera.sources import FrameGuard, FrameRejected
from taco_mav.config import Estimator
from taco_mav.core.localiser import Localiser
from taco_mav.cvgl.ground_motion import MIN_GAP_S, GroundMotion, HeadingHistory

if TYPE_CHECKING:
    from taco_mav.daemon.fixes import FixPipeline

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MotionResult:
    """One measurement: frame times t0, t1 (autopilot s), translation in frame 0's body axes (metres) and its
    1-sigma (metres), the correlation peak."""

    t0: float
    t1: float
    d_fwd: float
    d_left: float
    sigma_m: float
    response: float


class MotionPipeline:
    """fixes: the fix pipeline (its camera and clock mapping); interval_s: autopilot seconds between
    measurements; gap_s: the longest time between the two frames (shorter at speed, so the ground moves at most
    half the largest shift looked for); lag_s: how far behind the newest IMU time the second
    frame is asked for (a world camera has poses up to the last SIMSTATE, a live one frames up to now)."""

    def __init__(self, *, fixes: FixPipeline, interval_s: float = 0.5, gap_s: float = 0.3,
                 lag_s: float = 0.1) -> None:
        self.fixes = fixes
        self.interval_s, self.gap_s, self.lag_s = interval_s, gap_s, lag_s
        cam = fixes.ground_camera
        self.motion = GroundMotion(cam, ego_rows=fixes.profile.classical.ego_mask_rows)
        # frames undistorted as for fixes, grey (the BEV is grey: a JPEG's luma alone is decoded); a real (noisy)
        # camera never gives the same picture twice: a repeat is a hung driver, whose frames would read as a stop (a
        # noiseless renderer repeats itself legitimately); a freeze it sees is the matcher's too (FreezeWatch)
        source = fixes.camera
        self.guard = FrameGuard(cam.width, cam.height, max(fixes.opt.frame_max_gap_s, gap_s),
                                check_frozen=source is not None and not source.noiseless, rectifier=fixes.rectifier,
                                grey=True, freeze=fixes.guard.freeze if fixes.guard is not None else None)
        self.counts: Counter[str] = Counter()
        self.headings = HeadingHistory()
        self._jobs: queue.Queue[tuple[float, float] | None] = queue.Queue(maxsize=1)
        self._done: queue.Queue[MotionResult] = queue.Queue()
        self._next = -math.inf
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="taco-motion", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            try:
                self._jobs.put_nowait(None)
            except queue.Full:
                pass
            self._thread.join(1.0)

    def on_heading(self, t: float, theta: float) -> None:
        """The compass heading (ENU rad) at autopilot time t (s), for the heading change between frames."""
        self.headings.add(t, theta)

    def tick(self, loc: Localiser | None, twin: Localiser | None = None) -> None:
        """On the loop thread: ask for a new measurement when one is due; hand finished ones to the Localiser
        and the shadow twin (`add_ground_motion`, taco+ only)."""
        if loc is None:
            return
        self.on_heading(loc.t, float(loc.timeline.pre.theta))
        while True:
            try:
                r = self._done.get_nowait()
            except queue.Empty:
                break
            if loc.takes_ground_motion:
                used = loc.add_ground_motion(r.t0, r.t1, r.d_fwd, r.d_left, r.sigma_m)
                if twin is not None and twin.takes_ground_motion:
                    twin.add_ground_motion(r.t0, r.t1, r.d_fwd, r.d_left, r.sigma_m)
                self.counts[f"used_{used}"] += 1
                log.debug("camera motion %.2f-%.2f s: fwd %.3f left %.3f m (sigma %.3f, peak %.2f): %s", r.t0, r.t1,
                          r.d_fwd, r.d_left, r.sigma_m, r.response, used)
        if not loc.takes_ground_motion or loc.t < self._next:
            return
        self._next = loc.t + self.interval_s
        t1 = loc.t - self.lag_s
        gap = self.motion.frame_gap(float(loc.timeline.pre.speed), self.gap_s)
        try:
            self._jobs.put_nowait((t1 - gap, t1))
        except queue.Full:
            self.counts["busy"] += 1

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            try:
                r = self._measure(*job)
            except FrameRejected as e:
                self.counts[e.reason] += 1
                continue
            except Exception:  # noqa: BLE001 - a failed measurement must never stop the pipeline
                log.exception("camera motion")
                self.counts["error"] += 1
                continue
            if isinstance(r, str):
                self.counts[r] += 1
            else:
                self.counts["measured"] += 1
                self._done.put(r)

    def _measure(self, t0: float, t1: float) -> MotionResult | str:
        """The measurement between the frames nearest t0 and t1, or why there is none."""
        f0, f1 = self.fixes.frame_fetcher(t0, self.guard), self.fixes.frame_fetcher(t1, self.guard)
        if f0 is None or f1 is None:
            return "no_camera"
        a, b = f0(), f1()
        if b.t - a.t < 0.5 * MIN_GAP_S:
            return "same_frame"
        dtheta = self.headings.change(a.t, b.t)
        if dtheta is None:
            return "no_heading"
        m = self.motion.measure(a.image, b.image, dtheta)
        if m is None:
            return "weak"
        return MotionResult(a.t, b.t, m.d_fwd, m.d_left, m.sigma_m, m.response)


def start_camera_speed(fixes: FixPipeline) -> MotionPipeline | None:
    """taco+'s camera speed (plus.camera_speed) from the fix pipeline's camera: a started `MotionPipeline`, or None
    (no camera, paper mode, switched off, or a camera that sees too little ground ahead: fixes still work, the
    speed is the IMU's)."""
    p = fixes.profile
    if fixes.camera is None or not p.plus.camera_speed or p.estimator is not Estimator.TACO_PLUS:
        return None
    try:
        motion = MotionPipeline(fixes=fixes)
    except ValueError as e:
        log.warning("camera speed off (plus.camera_speed): %s", e)
        return None
    motion.start()
    return motion
