"""The daemon loop (`taco-mav run`): MAVLink IMU/attitude in, TACO Localiser, CVGL fixes from a worker thread,
GPS-style position out at a steady rate.

This module holds the lifecycle and the loop; the methods of one concern each live in a mixin: inputs
(`daemon_inputs`: message dispatch, IMU, attitude), origin and re-anchoring (`daemon_origin`: start position,
reboots, IMU gaps, real GNSS) and outputs (`daemon_outputs`: position messages, health, STATUSTEXT, summary).

Threads: the loop thread owns the Link and the Localiser (every Localiser call happens here); the fix pipeline
(`fixes.FixPipeline`: camera, map, matcher worker) runs FixService.answer in the worker thread and posts results
to a queue; a VideoCapture camera grabs in its own thread. Time: the filter runs on the autopilot clock (IMU
timestamps); `ClockMap` maps the companion clock onto it.

    d = Daemon(profile, DaemonOptions(connect="udpin:127.0.0.1:14550", log_dir=Path("run1")))
    d.start(); ...; d.stop(); d.join()          # or d.run() in the calling thread (the CLI)
"""

from __future__ import annotations

import dataclasses
import logging
import math
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable

from taco_mav.config import Estimator, Profile, localiser_params, profile_to_dict
from taco_mav.core import ukf_kernels
from taco_mav.core.localiser import Localiser
from taco_mav.cvgl.base import Matcher
from taco_mav.daemon.anchor import Anchor, OriginCandidate, OriginChooser
from taco_mav.daemon.daemon_inputs import DaemonInputs
from taco_mav.daemon.daemon_origin import DaemonOrigin
from taco_mav.daemon.daemon_outputs import DaemonOutputs
from taco_mav.daemon.drive import DriveCommand
from taco_mav.daemon.eventlog import EventLog
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.gcs import GCS_HEALTH_HZ, GcsHealth
from taco_mav.daemon.gnss import GnssTracker
from taco_mav.daemon.health import LinkWatch
from taco_mav.daemon.imu_source import InputSources
from taco_mav.daemon.imu_timeline import ImuTimeline
from taco_mav.daemon.motion import MotionPipeline
from taco_mav.daemon.options import DaemonOptions, DaemonStats
from taco_mav.daemon.output import OutputStage
from taco_mav.daemon.scheduler import AutopilotPeriodic, Periodic
from taco_mav.errors import ConfigError
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.decoders import IMU_MESSAGES, ORIGIN_MESSAGES, AttitudeReading, Decoders, ImuReading
from taco_mav.mavlink.mavconst import MAV_AUTOPILOT_PX4, SEV_INFO, SEV_NOTICE
from taco_mav.mavlink.reconnect import pace_tcp_reconnect
from taco_mav.mavlink.requests import GNSS_RATES, MessageRequest, ParamCheck, StreamRequester, ekf3_gate_warnings
from taco_mav.mavlink.timesync import ClockMap

log = logging.getLogger(__name__)

__all__ = ["Daemon", "DaemonOptions", "DaemonStats", "run_daemon"]


class Daemon(DaemonInputs, DaemonOrigin, DaemonOutputs):
    """One daemon run. `run()` blocks until `stop()` (or a signal via `run_daemon`); `start()` runs it in a
    thread. clock: companion monotonic seconds; wall_clock: UTC unix seconds (GPS week/ms, logs); matcher:
    use this matcher instead of the profile's (tests, embedding)."""

    def __init__(self, profile: Profile, options: DaemonOptions, clock: Callable[[], float] = time.monotonic,
                 wall_clock: Callable[[], float] = time.time, matcher: Matcher | None = None) -> None:
        if options.estimator is not None and options.estimator is not profile.estimator:
            profile = dataclasses.replace(profile, estimator=options.estimator)
        if profile.link.imu_message != "auto" and profile.link.imu_message not in IMU_MESSAGES:
            raise ConfigError(f"link.imu_message: {profile.link.imu_message!r} is not 'auto' or one of {IMU_MESSAGES}")
        options = dataclasses.replace(
            options, link_timeout_s=profile.link.timeout_s if options.link_timeout_s is None else options.link_timeout_s,
            matcher_timeout_s=(profile.map.matcher_timeout_s if options.matcher_timeout_s is None
                               else options.matcher_timeout_s))
        self.profile, self.opt = profile, options
        # The first run after an install compiles the UKF kernels (numba: seconds, a minute on a busy machine). Done
        # here, before `start()` opens the link, so the loop never stalls on it mid-drive; later runs load the cache.
        started = time.perf_counter()
        ukf_kernels.warm_up()
        log.debug("filter kernels ready in %.1f s", time.perf_counter() - started)
        self.clock, self.wall_clock = clock, wall_clock
        self.params = localiser_params(profile)
        self.stop_event = threading.Event()
        self.stats = DaemonStats()
        self.decoders = Decoders()
        self.clockmap = ClockMap(clock)
        self.output = OutputStage(profile, self._health_changed)
        self.fixes = FixPipeline(profile, options, self.clockmap, self.stats, self._status, matcher)
        self.linkwatch = LinkWatch(options.link_timeout_s)
        self.loc: Localiser | None = None
        self.motion: MotionPipeline | None = None  # camera speed (taco+, plus.camera_speed)
        self.anchor = Anchor(self.params)  # origin and Localiser generations (+1 at each re-anchoring)
        self.attitude: AttitudeReading | None = None
        self.imu_kind: str | None = None if profile.link.imu_message == "auto" else profile.link.imu_message
        self.sources = InputSources(profile.link.imu_message)  # IMU and attitude streams: first valid, fallback
        self.last_imu: ImuReading | None = None
        self.drive = DriveCommand()  # armed / driving, from the autopilot's HEARTBEAT and VFR_HUD
        self.timeline = ImuTimeline(profile.link.reboot_backstep_s, profile.imu.max_dt_s)
        self._last_imu_clock = -math.inf
        self._last_status: dict[str, float] = {}
        self._thread: threading.Thread | None = None
        self.exit_code: int | None = None
        self.link: Link | None = None

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

    def _setup(self) -> None:
        """Open logs, the link, the fix pipeline and the camera motion; request streams; start the timers."""
        p, opt = self.profile, self.opt
        log_dir = Path(opt.log_dir) if opt.log_dir else None
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            import yaml

            (log_dir / "config.yaml").write_text(yaml.safe_dump(profile_to_dict(p), sort_keys=False))
        self.events = EventLog(log_dir / "events.jsonl" if log_dir else None)
        self.fixes.open(self.events)
        self.link = Link(opt.connect, p.link.sysid, p.link.compid, p.link.baud,
                         tlog=log_dir / "mav.tlog" if log_dir else None, wall_clock=self.wall_clock,
                         signing_key=opt.signing_key, rejected=self.decoders.rejected,
                         udp_client_timeout_s=opt.link_timeout_s)
        pace_tcp_reconnect(self.link.conn)  # a TCP autopilot that goes away must not block the loop
        self.fixes.start()
        if self.fixes.camera is not None and p.plus.camera_speed and p.estimator is Estimator.TACO_PLUS:
            try:
                self.motion = MotionPipeline(self.fixes)
                self.motion.start()
            except ValueError as e:  # the camera sees too little ground ahead: fixes still work, speed is the IMU's
                log.warning("camera speed off (plus.camera_speed): %s", e)
        for text in ekf3_gate_warnings(p.output.satellites_visible, p.output.hdop_uere_m, p.output.hdop_min):
            log.warning("%s", text)
        self.requester: StreamRequester | None = None  # made when the autopilot is adopted (`_request_streams`)
        self.params_check = ParamCheck(self.link.send, self.link.mav, p.output.gps_id,
                                       antenna_frd_m=p.output.antenna_frd_m) if p.link.check_params and \
            "gps_input" in p.output.messages else None
        self.gnss = GnssTracker(p.output.gps_id, self.output.writes_gps, p.output.hdop_uere_m,
                                self.params_check.types if self.params_check is not None else None)
        self.origin_chooser = OriginChooser()
        self.origin_request = MessageRequest(self.link.send, self.link.mav, ORIGIN_MESSAGES)
        if opt.origin is not None:
            self._offer_origin(OriginCandidate(*opt.origin, speed=0.0, course=None, source="--origin"))
        now = self.clock()
        self.t_heartbeat = Periodic(p.link.heartbeat_hz, now)
        self.t_output = AutopilotPeriodic(p.output.rate_hz, now, self.clockmap.speed)  # rate in autopilot time
        self.t_timesync = Periodic(p.link.timesync_hz, now) if p.link.timesync_hz > 0 else None
        self.t_stats = Periodic(0.1, now + 10.0)
        self.gcs = GcsHealth()
        self.t_gcs = AutopilotPeriodic(GCS_HEALTH_HZ, now, self.clockmap.speed)  # NAMED_VALUE_FLOAT health

    def _request_streams(self, autopilot: int) -> None:
        """Ask the adopted autopilot (HEARTBEAT.autopilot: MAV_AUTOPILOT_*) for the input streams; a simulator's
        true pose (world camera, emulator matcher) is SIMSTATE on ArduPilot SITL and HIL_STATE_QUATERNION on PX4
        SIH (neither is sent unless asked for)."""
        p = self.profile
        if not p.link.request_rates:
            return
        rates = {"ATTITUDE": p.link.attitude_rate_hz, "SYSTEM_TIME": 1.0, "GPS_RAW_INT": 2.0, "VFR_HUD": 5.0}
        if (self.fixes.camera is not None and self.fixes.camera.needs_pose) or p.matcher == "emulator":
            rates["HIL_STATE_QUATERNION" if autopilot == MAV_AUTOPILOT_PX4 else "SIMSTATE"] = p.link.imu_rate_hz
        rates[self.imu_kind or "RAW_IMU"] = p.link.imu_rate_hz
        rates.update(GNSS_RATES)  # GNSS stays read after the origin: it is fused while it is honest
        assert self.link is not None
        self.requester = StreamRequester(self.link.send, self.link.mav, rates)

    def run(self) -> int:
        """The loop; returns 0 after a clean stop (logs flushed, threads stopped)."""
        try:
            self._setup()
            self.events.write("start", connect=self.opt.connect, camera=self.opt.camera, matcher=self.profile.matcher,
                              outputs=list(self.profile.output.messages), rate_hz=self.profile.output.rate_hz)
            self._status(SEV_INFO, "started", key=None)
            while not self.stop_event.is_set():
                self._step()
            self.exit_code = 0
        finally:
            self._shutdown()
        return self.exit_code or 0

    def _shutdown(self) -> None:
        """Stop threads, write the stop event with the summary, close the link and logs."""
        if self.link is not None and self.link.target_system:
            self._status(SEV_NOTICE, "stopping", key=None)
        if self.motion is not None:
            self.motion.stop()
        self.fixes.stop()
        if getattr(self, "events", None) is not None:
            self.events.write("stop", stats=self.summary())
            self.events.close()
        if self.link is not None:
            self.link.close()
        self.fixes.close()
        log.info("stopped: %s", self.summary())

    # ------------------------------------------------------------------ loop
    def _step(self) -> None:
        """One loop pass: receive (at most until the next output or heartbeat is due), handle, collect fixes."""
        now = self.clock()
        due = [self.t_output.next_due, self.t_heartbeat.next_due]
        timeout = min(0.02, max(0.0, min(due) - now))
        assert self.link is not None
        msgs = self.link.recv(timeout)
        received = time.perf_counter()
        for msg in msgs:
            try:
                self._handle(msg, received)
            except Exception:  # noqa: BLE001 - one bad message must never stop the loop
                log.exception("handling %s", msg.get_type())
                self.stats.dropped["handler_error"] += 1
        self.fixes.drain(self.loc, self.anchor.generation)
        self.fixes.poll(self.loc, self.anchor.generation)
        if self.motion is not None:
            self.motion.tick(self.loc)
        self._periodic(self.clock())

    def _periodic(self, now: float) -> None:
        """Whatever is due at companion time `now` (s): outputs, heartbeat, time sync, requests, origin, health."""
        link = self.link
        assert link is not None
        if self.t_output.due(now):
            self._send_outputs(now)
        if self.t_heartbeat.due(now):
            link.heartbeat()
        if self.t_timesync is not None and link.target_system and self.t_timesync.due(now):
            link.send(link.mav.timesync_encode(0, self.clockmap.request_ns()))
        if self.requester is not None:
            self.requester.tick(now, link.target_system, link.target_component)
        if self.params_check is not None:
            self.params_check.tick(now, link.target_system, link.target_component)
        self._origin_tick(now)
        if self.t_gcs.due(now) and link.target_system:  # on its grid from the start, sent once there is a target
            self._gcs_health(now)
        if self.t_stats.due(now):
            self.events.write("stats", **self.summary())
        if self.linkwatch.check(now):
            log.warning("link lost: nothing from the autopilot for %.1f s", self.opt.link_timeout_s)
            self.events.write("link_lost", silent_s=now - (self.linkwatch.last_heard or now))


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
