"""The daemon loop (`taco-mav run`): MAVLink IMU/attitude in, TACO Localiser, CVGL fixes from a worker thread,
GPS-style position out at a steady rate.

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

import numpy as np

from taco_mav.config import Estimator, Profile, localiser_params, profile_to_dict
from taco_mav.core.localiser import Localiser
from taco_mav.core.types import ImuSample
from taco_mav.cvgl.base import Matcher
from taco_mav.errors import ConfigError
from taco_mav.link import encoders
from taco_mav.link.anchor import GNSS_RANK, NO_ORIGIN_TEXTS, Anchor, OriginCandidate, OriginChooser
from taco_mav.link.connection import Link
from taco_mav.link.decoders import (GNSS_MESSAGES, IMU_MESSAGES, ORIGIN_MESSAGES, AttitudeReading, Decoders,
                                    GnssReading, ImuReading)
from taco_mav.link.eventlog import EventLog
from taco_mav.link.fixes import FixPipeline
from taco_mav.link.gcs import GCS_HEALTH_HZ, GcsHealth
from taco_mav.link.gnss import GnssEvent, GnssTracker
from taco_mav.link.health import LinkWatch
from taco_mav.link.imu_source import ATTITUDE_MESSAGES, ATTITUDE_STALE_S, InputSources
from taco_mav.link.imu_timeline import ImuTimeline, Verdict
from taco_mav.link.motion import MotionPipeline
from taco_mav.link.options import DaemonOptions, DaemonStats
from taco_mav.link.output import OutputStage
from taco_mav.link.reconnect import pace_tcp_reconnect
from taco_mav.link.requests import GNSS_RATES, MessageRequest, ParamCheck, StreamRequester, ekf3_gate_warnings
from taco_mav.link.scheduler import AutopilotPeriodic, Periodic
from taco_mav.link.timesync import ClockMap

log = logging.getLogger(__name__)

SEV_ERROR, SEV_WARNING, SEV_NOTICE, SEV_INFO = 3, 4, 5, 6
MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER = 6, 18
MAV_MODE_FLAG_SAFETY_ARMED = 128
DRIVE_THROTTLE_MIN_PCT = 3  # VFR_HUD throttle at or above this (armed) means the autopilot drives


__all__ = ["Daemon", "DaemonOptions", "DaemonStats", "run_daemon"]


class Daemon:
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
        self._armed: bool | None = None  # from the autopilot's HEARTBEAT
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
        self.stop_event.set()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def _setup(self) -> None:
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
            self.motion = MotionPipeline(self.fixes)
            self.motion.start()
        for text in ekf3_gate_warnings(p.output.satellites_visible, p.output.hdop_uere_m, p.output.hdop_min):
            log.warning("%s", text)
        rates = {"ATTITUDE": p.link.attitude_rate_hz, "SYSTEM_TIME": 1.0, "GPS_RAW_INT": 2.0, "VFR_HUD": 5.0}
        if (self.fixes.camera is not None and self.fixes.camera.needs_pose) or p.matcher == "emulator":
            rates["SIMSTATE"] = p.link.imu_rate_hz  # simulators only (SITL sends it when asked): true pose
        if self.imu_kind is not None:
            rates[self.imu_kind] = p.link.imu_rate_hz
        else:
            rates["RAW_IMU"] = p.link.imu_rate_hz
        rates.update(GNSS_RATES)  # GNSS stays read after the origin: it is fused while it is honest
        self.requester = StreamRequester(self.link.send, self.link.mav, rates) if p.link.request_rates else None
        self.params_check = ParamCheck(self.link.send, self.link.mav, p.output.gps_id) if p.link.check_params and \
            "gps_input" in p.output.messages else None
        self.gnss = GnssTracker(p.output.gps_id, "gps_input" in p.output.messages, p.output.hdop_uere_m,
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

    def _heard(self) -> None:
        """A message from our autopilot: ends a link outage (event + STATUSTEXT, now that it is reachable)."""
        outage = self.linkwatch.heard(self.clock())
        if outage is not None:
            text = f"link restored after {outage:.1f}s"
            log.warning("%s", text)
            self.events.write("link_restored", outage_s=outage)
            self._status(SEV_WARNING, text, key=None)

    # ------------------------------------------------------------------ inputs
    def _handle(self, msg: Any, received: float) -> None:
        kind = msg.get_type()
        link = self.link
        assert link is not None
        if kind == "HEARTBEAT":
            if (msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type not in (MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER)
                    and (self.profile.link.target_sysid in (0, msg.get_srcSystem()))):
                if link.adopt_autopilot(msg):
                    self.events.write("autopilot", sysid=link.target_system, compid=link.target_component)
                if (msg.get_srcSystem(), msg.get_srcComponent()) == (link.target_system, link.target_component):
                    self._heard()
                    self._armed = bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
            return
        if not link.target_system:
            self.decoders.reject(kind, "before_autopilot")
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (link.target_system, link.target_component):
            self.decoders.reject(kind, "foreign_source")  # only the adopted autopilot's messages are acted on
            return
        self._heard()
        if kind in IMU_MESSAGES:
            self._on_imu(msg, received)
        elif kind in ATTITUDE_MESSAGES:
            self.attitude = self.sources.attitude_reading(msg, self.decoders, self.clock()) or self.attitude
            self._source_switches()
        elif kind in GNSS_MESSAGES:
            self._on_gnss(msg)
        elif kind in ORIGIN_MESSAGES:
            o = self.decoders.origin(msg) if self.origin is None else None
            if o is not None:
                self._offer_origin(OriginCandidate(o.lat, o.lon, o.alt, 0.0, None, o.source))
        elif kind == "SYSTEM_TIME":
            self.clockmap.on_system_time(msg.time_boot_ms)
        elif kind == "TIMESYNC":
            if msg.tc1 == 0:  # the autopilot asks us: answer with our clock
                link.send(link.mav.timesync_encode(self.clockmap.request_ns(), msg.ts1))
            else:
                self.clockmap.on_timesync_reply(msg.tc1, msg.ts1)
        elif kind == "SIMSTATE":
            self._on_simstate(msg)
        elif kind == "VFR_HUD":
            self._on_vfr_hud(msg)
        elif kind == "COMMAND_ACK" and self.requester is not None:
            self.requester.on_message(msg, link.target_system, link.target_component)
        elif kind == "PARAM_VALUE" and self.params_check is not None:
            warning = self.params_check.on_message(msg)
            if warning:
                self._status(SEV_ERROR, warning, key=None)
                self.events.write("param_check", warning=warning)

    def _on_imu(self, msg: Any, received: float) -> None:
        r = self.sources.imu_reading(msg, self.decoders, self.clock())  # the chosen stream's valid samples only
        self._source_switches()
        if r is None:
            return
        check = self.timeline.check(r.t, self.loc is not None)
        if check.outlier:
            self.stats.dropped["imu_time_outlier"] += 1
        if check.verdict in (Verdict.UNCONFIRMED, Verdict.OUT_OF_ORDER):
            self.stats.dropped[check.verdict.value] += 1
            return
        if check.verdict is Verdict.REBOOT:
            self._reboot(check.t_from, check.t_to)
        elif check.verdict is Verdict.GAP:
            self._imu_gap(check.t_from, check.t_to)
        self.clockmap.on_autopilot_time(r.t)
        self.last_imu = r
        self._last_imu_clock = self.clock()
        if self.attitude is None:
            self.stats.dropped["imu_before_attitude"] += 1
            return
        a = self.attitude.at(r.t)
        if r.t - self.attitude.t > ATTITUDE_STALE_S:  # no valid attitude for a while: the last one is used
            self.stats.attitude_stale += 1
            self._status(SEV_WARNING, f"attitude stale {r.t - self.attitude.t:.1f}s", key="attitude_stale")
        if self.loc is None:
            if self.origin is None:
                self.stats.dropped["imu_before_origin"] += 1
                return
            self.loc = self.anchor.localiser(r.t, a.yaw)
        assert self.loc is not None
        self.loc.add_imu(ImuSample(r.t, r.accel_frd, r.gyro_frd, a.roll, a.pitch, a.yaw))
        self.stats.imu_samples += 1
        self.stats.imu_to_estimate_s.append(time.perf_counter() - received)

    def _source_switches(self) -> None:
        """Log, count (summary "sources") and write the IMU / attitude source chosen or changed; a fallback
        also goes to the ground station."""
        for what, sw in self.sources.take_switches():
            self.events.write("input_source", input=what, old=sw.old, new=sw.new, silent_s=sw.silent_s)
            if sw.old is None:
                log.info("%s input: %s", what.upper() if what == "imu" else what, sw.new)
                continue
            text = f"{what} {sw.old} silent {sw.silent_s:.1f}s: using {sw.new}"
            log.warning("%s", text)
            self._status(SEV_WARNING, text, key=None)

    def _on_vfr_hud(self, msg: Any) -> None:
        """The autopilot's throttle output (%): armed with throttle means it drives, which vetoes taco+'s
        zero-velocity updates (a smooth cruise looks still to the IMU, issue 19)."""
        throttle = getattr(msg, "throttle", None)
        if not isinstance(throttle, int) or not -100 <= throttle <= 100:
            self.decoders.reject("VFR_HUD", "range")
            return
        set_drive = getattr(self.loc, "set_drive_command", None)
        if set_drive is not None and self.last_imu is not None and self._armed is not None:
            set_drive(self.last_imu.t, self._armed and abs(throttle) >= DRIVE_THROTTLE_MIN_PCT)

    def _on_simstate(self, msg: Any) -> None:
        pose = self.decoders.simstate(msg)
        if pose is None or self.last_imu is None:
            return
        self.fixes.on_pose(self.last_imu.t, pose, self.origin)

    # ------------------------------------------------------------------ origin and re-anchoring
    @property
    def origin(self) -> encoders.Origin | None:
        return self.anchor.origin

    def _set_origin(self, lat: float, lon: float, alt: float, speed: float, course: float | None, source: str) -> None:
        origin = self.anchor.set_origin(lat, lon, alt, speed, course)
        log.info("origin from %s: %.7f, %.7f, %.1f m (UTM EPSG:%d), speed %.2f m/s", source, lat, lon, alt,
                 origin.projector.epsg, speed)
        self.events.write("origin", source=source, lat=lat, lon=lon, alt=alt, speed=speed, course_ned=course,
                          epsg=origin.projector.epsg, convergence_rad=origin.convergence)
        self._status(SEV_INFO, f"origin {lat:.6f},{lon:.6f} ({source})", key=None)
        self.fixes.on_origin(origin)

    def _reboot(self, t_last: float, t_new: float) -> None:
        """Autopilot clock went back: re-anchor at the current estimate on the new clock."""
        self.stats.reboots += 1
        text = f"autopilot reboot? time {t_last:.1f}s -> {t_new:.1f}s: re-anchored"
        log.warning("%s", text)
        self.events.write("reboot", t_last=t_last, t_new=t_new)
        self._status(SEV_WARNING, text, key="reboot")
        self.clockmap.reset()
        self.fixes.clear_truth()
        if self.loc is not None and self.attitude is not None:
            self.loc = self.anchor.restarted(self.loc, self.attitude.yaw, t_new)
        self.last_imu = None

    def _imu_gap(self, t_last: float, t_new: float) -> None:
        """No IMU from t_last to t_new (autopilot s), longer than the preintegrator bridges (imu.max_dt_s): the
        motion in between is unknown. Re-anchor at the estimate carried on at its speed and heading, with the
        1-sigma grown over the gap, so the output stays degraded until fixes bring it back."""
        assert self.loc is not None and self.attitude is not None
        c = self.anchor.carried(self.loc, t_last, t_new)
        self.stats.imu_gaps += 1
        log.warning("IMU gap %.1f s: re-anchored %.1f m ahead, sigma %.1f m", t_new - t_last, abs(c.carried_m), c.sigma)
        self.events.write("imu_gap", t_last=t_last, t_new=t_new, sigma_h=c.sigma, carried_m=c.carried_m)
        self.loc = self.anchor.localiser(t_new, self.attitude.yaw, c.xy, c.heading, c.speed, c.sigma)

    def _offer_origin(self, c: OriginCandidate) -> None:
        """An origin offered (--origin, EKF origin, home, a steady real GNSS): `OriginChooser` says when to take
        which."""
        chosen = self.origin_chooser.offer(c, self.clock())
        if chosen is not None:
            self._take_origin(chosen)

    def _take_origin(self, c: OriginCandidate) -> None:
        self._set_origin(c.lat, c.lon, c.alt, c.speed, c.course, c.source)
        if c.rank == GNSS_RANK:
            self.anchor.set_start((0.0, 0.0), c.speed, c.course, None, c.t)  # carried to the first IMU sample
        elif (fresh := self.gnss.fresh(self.clock())) is not None:
            self._start_from_gnss(fresh)

    def _start_from_gnss(self, r: GnssReading) -> None:
        """Before the first anchoring: a real fix's speed and course, and its position if the vehicle has moved
        away from the offered origin (`Anchor.start_from_fix`)."""
        assert self.origin is not None
        f = self.gnss.fix(r, self.origin, None)
        if f is not None and self.anchor.start_from_fix(f, r.speed, r.course_ned):
            self.events.write("start_from_gnss", instance=r.instance, x=float(f.xy[0]), y=float(f.xy[1]),
                              sigma_h_m=f.sigma_h_m)

    def _on_gnss(self, msg: Any) -> None:
        """GPS_RAW_INT / GPS2_RAW: a real instance's 3D fix offers the origin, then goes to the Localiser
        (`add_gnss`); our own instance's echo is only counted (`GnssTracker`)."""
        instance, now = GNSS_MESSAGES[msg.get_type()], self.clock()
        reading = self.decoders.gnss(msg) if self.gnss.is_real(instance) else None
        r, events = self.gnss.on_message(instance, reading, int(msg.fix_type), now, self.origin)
        self._gnss_events(events)
        if r is None:
            return
        if self.origin is None:
            if self.gnss.steady:
                self._offer_origin(OriginCandidate(r.lat, r.lon, r.alt, r.speed, r.course_ned, msg.get_type(), r.t))
            return
        if self.loc is None:
            self._start_from_gnss(r)
            return
        fix = self.gnss.fix(r, self.origin, self.last_imu.t if self.last_imu is not None else None)
        if fix is not None:
            self._gnss_events(self.gnss.outcome(self.loc.add_gnss(fix), now))

    def _gnss_events(self, events: list[GnssEvent]) -> None:
        for e in events:
            log.warning("%s", e.text) if e.severity == SEV_WARNING else log.info("%s", e.text)
            self.events.write(e.kind, **e.fields)
            self._status(e.severity if e.severity is not None else SEV_INFO, e.text, key=None)

    def _origin_tick(self, now: float) -> None:
        """Periodic: take an origin whose grace ran out; while none, ask for GPS_GLOBAL_ORIGIN / HOME_POSITION
        and say every 10 s how to give one; GNSS loss by silence."""
        link = self.link
        assert link is not None
        if self.origin is None:
            if link.target_system:
                self.origin_chooser.heard(now)
            chosen = self.origin_chooser.poll(now)
            if chosen is not None:
                self._take_origin(chosen)
        if self.origin is None:
            self.origin_request.tick(now, link.target_system, link.target_component)
            if self.origin_chooser.notice_due(now):
                ours = f"GPS{self.profile.output.gps_id + 1}" if "gps_input" in self.profile.output.messages else None
                log.warning("no origin yet: give one with --origin LAT,LON[,ALT], set the EKF origin or home from "
                            "the ground station, or connect a real GNSS with a 3D fix%s",
                            f" (not {ours}: that instance carries our own output)" if ours else "")
                self.events.write("no_origin", notices=self.origin_chooser.notices, gnss=self.gnss.summary())
                for text in NO_ORIGIN_TEXTS:
                    self._status(SEV_WARNING, text, key=None)
        self._gnss_events(self.gnss.tick(now))

    # ------------------------------------------------------------------ outputs
    def _send_outputs(self, now: float) -> None:
        if self.loc is None or self.origin is None or self.link is None:
            return
        gyro = self.last_imu.gyro_frd if self.last_imu else (0.0, 0.0, 0.0)
        for msg in self.output.messages(self.loc.estimate(), now - self._last_imu_clock, self.origin, self.link.mav,
                                        self.wall_clock(), self.clockmap.now_autopilot(), self.link.target_system,
                                        self.attitude, gyro, self.stats.reboots):
            self.link.send(msg)
        self.stats.output_times.append(now)

    def _gcs_health(self, now: float) -> None:
        """NAMED_VALUE_FLOAT health for the ground station; a change of mode: log, event and STATUSTEXT."""
        link = self.link
        assert link is not None
        svc = self.fixes.service.stats if self.fixes.service is not None else None
        gnss = self.gnss.summary()
        rep = self.gcs.update(now, self.loc.estimate() if self.loc is not None and self.origin is not None else None,
                              self.output.last_hacc_m, self.output.health.healthy,
                              "rejected" if gnss["rejecting"] else gnss["state"], self.stats.fixes,
                              svc.answered if svc else 0, svc.triggers_off_map if svc else 0, self.fixes.last_weight)
        t_ap = self.clockmap.now_autopilot()
        for name, value in rep.values:
            link.send(encoders.named_value_float(link.mav, int(t_ap * 1e3) if t_ap else 0, name, value))
        if rep.change is not None:
            severity, text = rep.change
            log.warning("%s", text) if severity <= SEV_WARNING else log.info("%s", text)
            self.events.write("mode", mode=self.gcs.mode.name, code=int(self.gcs.mode), text=text)
            self._status(severity, text, key=None)

    def _health_changed(self, text: str, healthy: bool) -> None:
        log.info("%s", text) if healthy else log.warning("%s", text)
        self.events.write("health", text=text, healthy=healthy)
        self._status(SEV_INFO if healthy else SEV_WARNING, text, key=None)

    def _status(self, severity: int, text: str, key: str | None) -> None:
        """STATUSTEXT to the autopilot (and the log); `key` rate-limits by output.statustext_interval_s."""
        now = self.clock()
        if key is not None:
            if now - self._last_status.get(key, -math.inf) < self.profile.output.statustext_interval_s:
                return
            self._last_status[key] = now
        log.info("STATUSTEXT: %s", text)
        if self.link is not None:
            self.link.send(encoders.statustext(self.link.mav, severity, text))

    def summary(self) -> dict[str, Any]:
        """Counters for logs and tests; output_slots_skipped: output periods missed because the loop ran late
        (a stalled machine; each one is a GPS_INPUT the autopilot did not get)."""
        lat = np.array(self.stats.imu_to_estimate_s) * 1e3
        return {"imu_samples": self.stats.imu_samples, "queries": self.stats.queries, "fixes": dict(self.stats.fixes),
                "dropped": dict(self.stats.dropped), "rejected_inputs": dict(self.decoders.rejected),
                "outputs": len(self.stats.output_times),
                "output_slots_skipped": self.t_output.skipped if hasattr(self, "t_output") else 0,
                "reboots": self.stats.reboots, "imu_gaps": self.stats.imu_gaps,
                "sources": self.sources.summary(), "attitude_stale": self.stats.attitude_stale,
                "link_outages": self.linkwatch.outages, "link_lost": self.linkwatch.lost,
                "crops_off_map": self.fixes.service.stats.crops_off_map if self.fixes.service else 0,
                "mode": self.gcs.mode.name if hasattr(self, "gcs") else None,
                "camera_motion": dict(self.motion.counts) if self.motion is not None else None,
                "stuck_matchers": self.fixes.stuck,
                "imu_to_estimate_p99_ms": float(np.percentile(lat, 99)) if len(lat) else None,
                "clock_source": self.clockmap.source, "clock_speed": self.clockmap.speed(),
                "healthy": self.output.health.healthy,
                "sent": self.link.sent if self.link else 0, "received": self.link.received if self.link else 0,
                "estimator": self._estimator_state()}

    def _estimator_state(self) -> dict[str, Any] | None:
        """The estimate's 1-sigma (m) and the mode's internal state (taco+: lock, speed error m/s, accelerometer
        bias m/s^2, compass bias rad, fix-noise scale) for the periodic stats line; non-finite values as None."""
        if self.loc is None:
            return None
        est = self.loc.estimate()
        state = {"mode": self.profile.estimator.value, "sigma_h_m": est.sigma_h, **est.extra}
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in state.items()}


def run_daemon(profile: Profile, options: DaemonOptions) -> int:
    """Run the daemon in this thread until SIGINT/SIGTERM; returns the exit code (0 on a clean stop)."""
    daemon = Daemon(profile, options)
    previous: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: daemon.stop())
    try:
        return daemon.run()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
