"""The daemon loop (`taco-mav run`): MAVLink IMU/attitude in, TACO Localiser, CVGL fixes from a worker thread,
GPS-style position out at a steady rate.

`Daemon` owns the lifecycle and a small loop over handlers, each owning its own state behind two hooks (the
messages it takes, by type, and what it does when its time comes): `AutopilotLink` (adoption, our HEARTBEAT,
time sync, stream requests, the parameter check, link liveness), `Inputs` (IMU, attitude, throttle, a
simulator's pose), `OriginHandler` (the origin, real GNSS) and `Outputs` (position messages, health, the ground
station's view). What they share is `LiveState` (origin, Localiser, latest readings) and one `Reporter`.

Threads: the loop thread owns the Link and the Localiser (every Localiser call happens here); the fix pipeline
(`fixes.FixPipeline`: camera, map, matcher worker) runs FixService.answer in the worker thread and posts results
to a queue; a VideoCapture camera grabs in its own thread. Time: the filter runs on the autopilot clock (IMU
timestamps); `ClockMap` maps the companion clock onto it.

    d = Daemon(profile, DaemonOptions(connect="udpin:127.0.0.1:14550", log_dir=Path("run1")))
    d.start(); ...; d.stop(); d.join()          # or d.run() in the calling thread (the CLI)
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from taco_mav.config import Profile, localiser_params, profile_to_dict
from taco_mav.core import kernels
from taco_mav.core.localiser import Localiser
from taco_mav.cvgl.base import Matcher
from taco_mav.cvgl.registry import needs_true_pose
from taco_mav.daemon.anchor import LocaliserAnchor
from taco_mav.daemon.autopilot import WAKE_S, AutopilotLink
from taco_mav.daemon.clock import MONOTONIC, CompanionClock
from taco_mav.daemon.eventlog import EventLog
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.gnss import GnssTracker
from taco_mav.daemon.inputs import Inputs
from taco_mav.daemon.motion import MotionPipeline, start_camera_speed
from taco_mav.daemon.options import DaemonOptions, DaemonStats, resolve
from taco_mav.daemon.origin import OriginHandler
from taco_mav.daemon.outputs import Outputs
from taco_mav.daemon.record import FrameRecorder, start_recording
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.shadow import Shadow
from taco_mav.daemon.state import LiveState
from taco_mav.daemon.true_pose import TruePoseTrack
from taco_mav.mavlink import encoders
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.decoders import Decoders
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_NOTICE
from taco_mav.mavlink.reconnect import pace_tcp_reconnect
from taco_mav.mavlink.requests import ParamCheck, ekf3_gate_warnings
from taco_mav.mavlink.timesync import ClockMap

log = logging.getLogger(__name__)

__all__ = ["Daemon", "DaemonOptions", "DaemonStats", "run_daemon"]

Handler = Callable[[Any, float], None]


class Daemon:
    """One daemon run. `run()` blocks until `stop()` (or a signal via `run_daemon`); `start()` runs it in a
    thread. clock: companion monotonic seconds (a simulator's says so: `CompanionClock.simulated`); wall_clock:
    UTC unix seconds (GPS week/ms, logs); matcher: use this matcher instead of the profile's (tests, embedding)."""

    def __init__(self, profile: Profile, options: DaemonOptions, *, clock: CompanionClock = MONOTONIC,
                 wall_clock: Callable[[], float] = time.time, matcher: Matcher | None = None) -> None:
        profile, options = resolve(profile, options)
        self.profile, self.opt = profile, options
        # Not built ahead of time (core/ukf_aot.py), numba compiles the kernels here, never in the loop mid-drive
        started = time.perf_counter()
        kernels.warm_up()
        log.debug("filter kernels ready in %.1f s", time.perf_counter() - started)
        self.clock, self.wall_clock = clock, wall_clock
        self.params = localiser_params(profile)
        self.stop_event = threading.Event()
        self.stats = DaemonStats()
        self.decoders = Decoders()
        self.clockmap = ClockMap(clock)
        self.reporter = Reporter(clock, profile.output.statustext_interval_s)
        # the simulator's true pose (SIMSTATE), kept only for a matcher that answers from it
        self.truth = TruePoseTrack() if needs_true_pose(profile, matcher) else None
        self.fixes = FixPipeline(profile=profile, options=options, clockmap=self.clockmap, stats=self.stats,
                                 status=self.reporter.status, matcher=matcher, truth=self.truth)
        self.state = LiveState(LocaliserAnchor(self.params), shadow=Shadow() if options.shadow else None)
        self.motion: MotionPipeline | None = None  # camera speed (taco+, plus.camera_speed), made when opened
        self.recorder: FrameRecorder | None = None  # --record: the camera's frames into the session folder
        assert options.link_timeout_s is not None
        self.autopilot = AutopilotLink(profile=profile, clockmap=self.clockmap, reporter=self.reporter,
                                       link_timeout_s=options.link_timeout_s, wants_pose=self._wants_pose)
        self.inputs = Inputs(profile=profile, state=self.state, stats=self.stats, decoders=self.decoders,
                             clockmap=self.clockmap, fixes=self.fixes, reporter=self.reporter, clock=clock,
                             truth=self.truth, wheel_pos_y=self.autopilot.wheel_pos_y)
        self.origins = OriginHandler(profile=profile, state=self.state, decoders=self.decoders, fixes=self.fixes,
                                     reporter=self.reporter, clock=clock)
        self.outputs = Outputs(profile=profile, state=self.state, stats=self.stats, clockmap=self.clockmap,
                               fixes=self.fixes, reporter=self.reporter, wall_clock=wall_clock,
                               gnss=self.origins.gnss, summary=self.summary)
        self.dispatch = self._dispatch_table(self.autopilot.handlers(), self.inputs.handlers(), self.origins.handlers())
        self.link: Link | None = None
        self.exit_code: int | None = None
        self._thread: threading.Thread | None = None
        self._passed = -math.inf  # companion s of the last read of the link
        self._wake = WAKE_S if clock.simulated else math.inf  # wall s of a wait's step on a simulator's clock

    @staticmethod
    def _dispatch_table(*tables: dict[str, Handler]) -> dict[str, Handler]:
        """One handler per message type: the handlers' tables merged (a type claimed twice is a bug)."""
        out: dict[str, Handler] = {}
        for table in tables:
            twice = set(out) & set(table)
            if twice:
                raise AssertionError(f"message types with two handlers: {sorted(twice)}")
            out.update(table)
        return out

    def _wants_pose(self) -> bool:
        """The simulator's true pose is needed: by a camera that renders from it, or a matcher that answers from it."""
        camera = self.fixes.camera
        return (camera is not None and camera.needs_pose) or self.truth is not None

    # ------------------------------------------------------------------ what tests and tools read
    @property
    def loc(self) -> Localiser | None:
        return self.state.loc

    @property
    def origin(self) -> encoders.Origin | None:
        return self.state.origin

    @property
    def anchor(self) -> LocaliserAnchor:
        return self.state.anchor

    @property
    def gnss(self) -> GnssTracker:
        return self.origins.gnss

    @property
    def params_check(self) -> ParamCheck | None:
        return self.autopilot.params_check

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Run the loop in a background thread."""
        self._thread = threading.Thread(target=self.run, name="taco-daemon", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Ask the loop to stop (any thread); `join` waits for it."""
        self.stop_event.set()

    def join(self, timeout: float | None = None) -> None:
        """Wait for the loop thread started by `start`."""
        if self._thread is not None:
            self._thread.join(timeout)

    def _open(self) -> None:
        """Open logs, the link, the fix pipeline and the camera motion; hand the link to the handlers and start
        their schedules."""
        p, opt = self.profile, self.opt
        log_dir = Path(opt.log_dir) if opt.log_dir else None
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            import yaml

            (log_dir / "config.yaml").write_text(yaml.safe_dump(profile_to_dict(p), sort_keys=False))
        events = EventLog(log_dir / "events.jsonl" if log_dir else None)
        self.fixes.open(events)
        self.link = Link(opt.connect, p.link.sysid, p.link.compid, p.link.baud,
                         tlog=log_dir / "mav.tlog" if log_dir else None, wall_clock=self.wall_clock,
                         signing_key=opt.signing_key, rejected=self.decoders.rejected,
                         udp_client_timeout_s=opt.link_timeout_s)
        self.reporter.open(events, self.link)
        pace_tcp_reconnect(self.link.conn)  # a TCP autopilot that goes away must not block the loop
        self.fixes.start()
        if opt.record is not None:
            self.recorder = start_recording(log_dir=log_dir, camera=self.fixes.camera, clockmap=self.clockmap,
                                            options=opt.record, reporter=self.reporter, clock=self.clock)
        self.motion = start_camera_speed(self.fixes)
        for text in ekf3_gate_warnings(p.output.satellites_visible, p.output.hdop_uere_m, p.output.hdop_min):
            log.warning("%s", text)
        now = self.clock()
        self.autopilot.open(self.link, now)
        checked = self.autopilot.params_check
        self.origins.open(self.link, checked.types if checked is not None else None, opt.origin)
        self.outputs.open(self.link, now)

    def run(self) -> int:
        """The loop; returns 0 after a clean stop (logs flushed, threads stopped)."""
        try:
            self._open()
            self.reporter.event("start", connect=self.opt.connect, camera=self.opt.camera,
                                matcher=self.profile.matcher, outputs=list(self.profile.output.messages),
                                rate_hz=self.profile.output.rate_hz)
            self.reporter.status(SEV_INFO, "started")
            while not self.stop_event.is_set():
                self._step()
            self.exit_code = 0
        finally:
            self._shutdown()
        return self.exit_code or 0

    def _shutdown(self) -> None:
        """Stop threads, write the stop event with the summary, close the link and logs."""
        if self.link is not None and self.link.target_system:
            self.reporter.status(SEV_NOTICE, "stopping")
        if self.motion is not None:
            self.motion.stop()
        if self.recorder is not None:
            self.recorder.stop()
        self.fixes.stop()
        if self.state.shadow is not None:
            line = self.state.shadow.line()
            log.info("%s", line)
            self.reporter.status(SEV_INFO, line[:50])
        self.reporter.event("stop", stats=self.summary())
        self.reporter.close()
        if self.link is not None:
            self.link.close()
        self.fixes.close()
        log.info("stopped: %s", self.summary())

    # ------------------------------------------------------------------ loop
    def _step(self) -> None:
        """One pass: receive (a read period after the last, or an output or heartbeat due), handle, collect fixes."""
        now = self.clock()
        due = min(self.outputs.next_due, self.autopilot.next_due)
        period = self.autopilot.read_period(now)  # companion s; waited for at most as long in wall s
        until, give_up = min(self._passed + period, due), time.monotonic() + period
        while now < until and time.monotonic() < give_up:  # short steps: a simulator's clock may run faster
            time.sleep(min(until - now, self._wake))
            now = self.clock()
        assert self.link is not None
        msgs = self.link.recv(min(0.02, max(0.0, due - now)))
        self._passed = self.clock()
        received = time.perf_counter()
        for msg in msgs:
            try:
                self._handle(msg, received)
            except Exception:  # noqa: BLE001 - one bad message must never stop the loop
                log.exception("handling %s", msg.get_type())
                self.stats.dropped["handler_error"] += 1
        self.outputs.tick(self.clock())  # a due output goes before the fixes' replays and the camera's speed
        loc, generation, twin = self.state.loc, self.state.anchor.generation, self.state.twin
        self.fixes.drain(loc, generation, self.state.shadow)
        self.fixes.poll(loc, generation, twin)
        if self.motion is not None:
            self.motion.tick(self.state.loc, twin)
        self._periodic(self.clock())

    def _handle(self, msg: Any, received: float) -> None:
        """One decoded message: a HEARTBEAT may adopt the autopilot; anything else goes to its handler only when
        it comes from the adopted autopilot. received: perf_counter seconds at receipt (IMU-to-estimate latency)."""
        kind = msg.get_type()
        link = self.link
        assert link is not None
        if kind == "HEARTBEAT":
            if self.autopilot.on_heartbeat(msg):
                self.autopilot.heard(self.clock())
                self.inputs.on_heartbeat(msg)
            return
        if not link.target_system:
            self.decoders.reject(kind, "before_autopilot")
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (link.target_system, link.target_component):
            self.decoders.reject(kind, "foreign_source")  # only the adopted autopilot's messages are acted on
            return
        self.autopilot.heard(self.clock(), kind)
        handler = self.dispatch.get(kind)
        if handler is not None:
            handler(msg, received)

    def _periodic(self, now: float) -> None:
        """Whatever is due at companion time `now` (s): outputs, our heartbeat and requests, the origin, the
        ground station's health, link liveness."""
        self.outputs.tick(now)
        self.autopilot.tick(now)
        self.origins.tick(now)
        self.outputs.tick_reports(now)
        self.autopilot.watch(now)

    # ------------------------------------------------------------------ counters
    def summary(self) -> dict[str, Any]:
        """Counters for logs and tests; output_slots_skipped: output periods missed because the loop ran late
        (a stalled machine; each one is a GPS_INPUT the autopilot did not get)."""
        lat = np.array(self.stats.imu_to_estimate_s) * 1e3
        watch = self.autopilot.linkwatch
        return {"imu_samples": self.stats.imu_samples, "queries": self.stats.queries, "fixes": dict(self.stats.fixes),
                "dropped": dict(self.stats.dropped), "rejected_inputs": dict(self.decoders.rejected),
                "outputs": len(self.stats.output_times), "output_slots_skipped": self.outputs.t_output.skipped,
                "reboots": self.stats.reboots, "imu_gaps": self.stats.imu_gaps,
                "sources": self.inputs.sources.summary(), "attitude_stale": self.stats.attitude_stale,
                "link_outages": watch.outages, "link_lost": watch.lost,
                "crops_off_map": self.fixes.service.stats.crops_off_map if self.fixes.service else 0,
                "mode": self.outputs.gcs.mode.name,
                "camera_motion": dict(self.motion.counts) if self.motion is not None else None,
                "stuck_matchers": self.fixes.stuck,
                "imu_to_estimate_p99_ms": float(np.percentile(lat, 99)) if len(lat) else None,
                "clock_source": self.clockmap.source, "clock_speed": self.clockmap.speed(),
                "healthy": self.outputs.stage.health.healthy,
                "sent": self.link.sent if self.link else 0, "received": self.link.received if self.link else 0,
                "recorded": self.recorder.summary() if self.recorder is not None else None,
                "shadow": self.state.shadow.summary() if self.state.shadow is not None else None,
                "estimator": self._estimator_state()}

    def _estimator_state(self) -> dict[str, Any] | None:
        """The estimate's 1-sigma (m) and the mode's internal state (taco+: lock, speed error m/s, accelerometer
        bias m/s^2, compass bias rad, fix-noise scale) for the periodic stats line; non-finite values as None."""
        loc = self.state.loc
        if loc is None:
            return None
        est = loc.estimate()
        state = {"mode": self.profile.estimator.value, "sigma_h_m": est.sigma_h, **est.extra}
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in state.items()}


def run_daemon(profile: Profile, options: DaemonOptions) -> int:
    """Run the daemon in this thread until SIGINT/SIGTERM; returns the exit code: the daemon's own (0 on a clean
    stop) after SIGTERM (systemd's stop), 128 + SIGINT = 130 after Ctrl-C (the same clean stop, reported as a
    shell reports an interrupt)."""
    daemon = Daemon(profile, options)
    received: list[int] = []

    def on_signal(signum: int, _frame: Any) -> None:
        received.append(signum)
        daemon.stop()

    previous: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, on_signal)
    try:
        rc = daemon.run()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 128 + signal.SIGINT if signal.SIGINT in received else rc
