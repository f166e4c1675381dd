"""`Simulator`: an ArduPilot rover played from a drive over MAVLink, scoring the GPS_INPUT it gets back.

Streams (sysid/compid 1/1, ardupilotmega, MAVLink 2), stamped on the simulated autopilot clock (`SimClock`,
seconds since boot; drive time 0 plays at `play_start`): HEARTBEAT and SYSTEM_TIME at 1 Hz, RAW_IMU,
ATTITUDE and SIMSTATE at the drive's data rate, GPS_RAW_INT (GPS1) and GPS2_RAW (GPS2, unless GPS2_TYPE is 0)
at 5 Hz, HOME_POSITION and GPS_GLOBAL_ORIGIN at 1 Hz (the home, unless `send_home` is off). The GPS instance
whose type is 14 echoes the companion's GPS_INPUT (`receiver.EchoInstance`); the other is the drive's real
receiver (`receiver.GnssReceiver`: noise, denial, spoofing). SCALED_IMU and HIGHRES_IMU stream once a companion
asks with SET_MESSAGE_INTERVAL; asked intervals thin the data-rate streams too; MAV_CMD_REQUEST_MESSAGE sends
one at the next sample. Parameters, commands and TIMESYNC are answered by `AutopilotServices`; every GPS_INPUT
goes through `GpsInputMonitor` (ArduPilot's driver and EKF gates), serving the type-14 instance.

Playback waits (sending HEARTBEATs) until the companion's HEARTBEAT is heard, so nothing is played into a
closed port. With `lockstep` the clock is held and moved sample by sample (each sample is sent before the
clock reaches its time), at most at `speed`, and never more than `lockstep_lead_s` (one 5 Hz period) past the
companion's last GPS_INPUT: a companion paced on this clock (`Simulator.clock` injected, as the in-process
tests and the demo do) then always meets ArduPilot's 245 ms rule and sees the same inputs whatever its load;
a slower companion stretches wall time instead of missing its rate. Until the companion's first GPS_INPUT there
is nothing to hold the clock to (it needs the origin and the first samples to start), so the drive plays at
real time meanwhile, as an autopilot would: at `speed` the companion's start-up work (its requests, its
parameter reads) would leave its first estimates that many times further behind the vehicle.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from taco_mav.errors import ConfigError, TacoError  # noqa: E402
from taco_mav.mavlink.mavconst import GPS_TYPE_MAV  # noqa: E402
from taco_mav.sim import encode  # noqa: E402
from taco_mav.sim.clock import SimClock  # noqa: E402
from taco_mav.sim.gps_mav import GpsInputMonitor  # noqa: E402
from taco_mav.sim.receiver import (GPS_FIX_TYPE_3D_FIX, EchoInstance, GnssReceiver, GnssState,  # noqa: E402
                                   gps_message)
from taco_mav.sim.services import AutopilotServices  # noqa: E402
from taco_mav.sim.source import SimDrive, open_drive  # noqa: E402

log = logging.getLogger(__name__)

__all__ = ["SimOptions", "Simulator"]

M = mavutil.mavlink
DATA_STREAMS = (M.MAVLINK_MSG_ID_RAW_IMU, M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_SIMSTATE,
                M.MAVLINK_MSG_ID_SCALED_IMU, M.MAVLINK_MSG_ID_HIGHRES_IMU)
M_PER_DEG = 111_320.0  # metres per degree of latitude (the autopilot's dead reckoning, metres over seconds)
# message id -> default interval, s (0 = every data sample, -1 = off until asked for)
DEFAULT_INTERVALS: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0, M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0, M.MAVLINK_MSG_ID_GPS_RAW_INT: 0.2,
    M.MAVLINK_MSG_ID_RAW_IMU: 0.0, M.MAVLINK_MSG_ID_ATTITUDE: 0.0, M.MAVLINK_MSG_ID_SIMSTATE: 0.0,
    M.MAVLINK_MSG_ID_SCALED_IMU: -1.0, M.MAVLINK_MSG_ID_HIGHRES_IMU: -1.0, M.MAVLINK_MSG_ID_GPS2_RAW: 0.2,
    M.MAVLINK_MSG_ID_HOME_POSITION: 1.0, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: 1.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: -1.0,
}


@dataclass(frozen=True)
class SimOptions:
    """speed: real-time factor; deny_after_s: drive seconds of real GNSS (1.0 = the start-up fix only, sent
    five times in the first second; 0 = never a fix; inf = never denied); duration_s: play at most this much
    of the drive; lockstep: see the module docstring; gps1_type / gps2_type: the GPS1_TYPE / GPS2_TYPE
    parameters (14 = MAVLink; gps2_type None: 1 when gps1_type is 14, else 14); gnss_noise_m: the real
    receiver's 1-sigma (white + Gauss-Markov bias, seeded by `seed`); spoof_after_s / spoof_drift_mps /
    spoof_jump_m / spoof_bearing_deg: spoofing (receiver.py); home: (lat, lon, alt m AMSL) for HOME_POSITION and
    GPS_GLOBAL_ORIGIN (None: the drive's start), send_home False: neither is ever sent; wait_companion_s: how
    long to wait for the companion's HEARTBEAT before playing anyway; drain_s: wall seconds to keep listening
    after the drive ends; boot_offset_s: autopilot uptime when the simulator starts; pose_stream: SIMSTATE (the
    true pose) at the data rate unasked (False: only once a companion asks for it, as an autopilot that has no
    true pose to give, e.g. to measure what a run with a real camera costs, `taco_mav.bench.companion`);
    score_from_s: drive seconds played before the GPS_INPUT stream's rate, gaps and fix types are scored (a
    companion's start-up; the track's errors are scored throughout): beside a free-running simulator the daemon
    paces on a clock speed it learns from the IMU stamps in its first 0.1-0.3 s, while ArduPilot's GPS checks
    want 10 s of good data before the EKF uses a receiver."""

    speed: float = 1.0
    deny_after_s: float = 1.0
    duration_s: float | None = None
    lockstep: bool = False
    gps1_type: int = 14
    gps2_type: int | None = None
    gnss_noise_m: float = 1.0
    seed: int = 0
    spoof_after_s: float | None = None
    spoof_drift_mps: float = 0.0
    spoof_jump_m: float = 0.0
    spoof_bearing_deg: float = 90.0
    home: tuple[float, float, float] | None = None
    send_home: bool = True
    sysid: int = 1
    compid: int = 1
    wait_companion_s: float = 30.0
    drain_s: float = 1.0
    boot_offset_s: float = 5.0
    pose_stream: bool = True
    score_from_s: float = 0.0
    # one 5 Hz output period; the microsecond lets a companion whose grid is float-rounded past it still fire
    lockstep_lead_s: float = 0.200001
    # wall seconds to wait for a late GPS_INPUT: long enough for a companion stalled by a loaded machine (a
    # 2-core CI runner under GC and scheduling stalls missed 1 s once); once it has been missed, the waits drop
    # to `lockstep_timeout_behind_s` until the companion catches up, so one that stopped sending costs little
    lockstep_timeout_s: float = 5.0
    lockstep_timeout_behind_s: float = 0.25

    def check(self) -> None:
        """ConfigError for values out of range."""
        if not 0.0 < self.speed <= 100.0:
            raise ConfigError(f"--speed: {self.speed} is out of range (0 < speed <= 100)")
        if self.score_from_s < 0:
            raise ConfigError(f"--score-from: {self.score_from_s} must be >= 0 s")
        if self.deny_after_s < 0:
            raise ConfigError(f"--deny-after: {self.deny_after_s} must be >= 0 s")
        if self.duration_s is not None and self.duration_s <= 0:
            raise ConfigError(f"--duration: {self.duration_s} must be > 0 s")
        if not 0.0 <= self.gnss_noise_m <= 100.0:
            raise ConfigError(f"--gnss-noise: {self.gnss_noise_m} is out of range (0..100 m)")
        if self.spoof_after_s is not None and self.spoof_after_s < 0:
            raise ConfigError(f"--spoof-after: {self.spoof_after_s} must be >= 0 s")
        if not (0.0 <= self.spoof_drift_mps <= 100.0 and 0.0 <= self.spoof_jump_m <= 100_000.0):
            raise ConfigError("--spoof-drift / --spoof-jump: must be >= 0 (at most 100 m/s, 100 km)")
        for name, value in (("--gps1-type", self.gps1_type), ("--gps2-type", self.gps2_type)):
            if value is not None and not 0 <= value <= 30:
                raise ConfigError(f"{name}: {value} is not a GPS type (0..30)")
        if self.home is not None and not (-90.0 <= self.home[0] <= 90.0 and -180.0 <= self.home[1] <= 180.0):
            raise ConfigError(f"--home: {self.home} is not LAT,LON,ALT in degrees and metres")

    @property
    def gps_types(self) -> tuple[int, int]:
        """(GPS1_TYPE, GPS2_TYPE), GPS2_TYPE derived when not given: the other instance is the real receiver."""
        gps2 = self.gps2_type if self.gps2_type is not None else (1 if self.gps1_type == GPS_TYPE_MAV else GPS_TYPE_MAV)
        return self.gps1_type, gps2


class Simulator:
    """Play `drive` (a SimDrive or a drive/world folder) to a companion on `connect` (a pymavlink connection
    string; e.g. "udpout:127.0.0.1:14550" when the companion listens with udpin).

    start() opens the link and starts the player and receiver threads; stop() ends playback early; join()
    waits for the end; `results()` then gives the scored results (see score.py)."""

    def __init__(self, drive: SimDrive | Path | str, connect: str, speed: float = 1.0,
                 options: SimOptions | None = None, **overrides: Any) -> None:
        base = options or SimOptions()
        self.options = SimOptions(**{**asdict(base), "speed": speed, **overrides})
        self.options.check()
        self.drive = drive if isinstance(drive, SimDrive) else open_drive(Path(drive))
        self.connect = connect
        self.clock = SimClock(self.options.speed, self.options.boot_offset_s)
        o = self.options
        types = o.gps_types
        # ArduPilot's GPS_INPUT driver serves the type-14 instance (gps_id = instance - 1); none: all dropped
        self.monitor = GpsInputMonitor(instance=types.index(GPS_TYPE_MAV) if GPS_TYPE_MAV in types else -1)
        self.receiver = GnssReceiver(self.drive, o.gnss_noise_m, o.seed, o.deny_after_s, o.spoof_after_s,
                                     o.spoof_drift_mps, o.spoof_jump_m, o.spoof_bearing_deg)
        self.echo = EchoInstance()
        self._echo_t = 0.0  # autopilot s the echo's GPS_INPUT was kept
        d = self.drive
        self.home = o.home if o.home is not None else (float(d.true_lat[0]), float(d.true_lon[0]), float(d.alt[0]))
        self.statustexts: list[tuple[float, int, str]] = []
        self.companion: tuple[int, int] | None = None
        self.play_start: float | None = None
        self.play_end: float | None = None
        self.lockstep_timeouts = 0
        self._lockstep_behind = False
        self.sent_counts: dict[str, int] = {}
        self.error: BaseException | None = None
        self._conn: Any = None
        self._services: AutopilotServices | None = None
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._done = threading.Event()
        self._companion_seen = threading.Event()
        self._gps_event = threading.Condition()
        self._threads: list[threading.Thread] = []

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Open the connection and start playing (returns at once)."""
        if self._threads:
            raise TacoError("simulator already started")
        try:
            self._conn = mavutil.mavlink_connection(self.connect, source_system=self.options.sysid,
                                                    source_component=self.options.compid, dialect="ardupilotmega")
        except (OSError, ValueError) as exc:
            raise TacoError(f"--connect {self.connect!r}: cannot open ({exc})") from None
        self._conn.mav.robust_parsing = True
        self._services = AutopilotServices(self._conn.mav, self.options.sysid, self.options.compid,
                                           self.options.gps1_type, frozenset(DEFAULT_INTERVALS),
                                           gps2_type=self.options.gps_types[1])
        self._threads = [threading.Thread(target=self._guard(self._receive), name="sim-recv", daemon=True),
                         threading.Thread(target=self._guard(self._play), name="sim-play", daemon=True)]
        for th in self._threads:
            th.start()
        log.info("simulator: playing %s to %s at %gx%s", self.drive.name, self.connect, self.options.speed,
                 " (lockstep)" if self.options.lockstep else "")

    def stop(self) -> None:
        """End playback now (results cover what was played)."""
        self._stop.set()

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the end of playback and draining; True when finished. Re-raises a thread's error."""
        finished = self._done.wait(timeout)
        if finished:
            self._stop.set()
            for th in self._threads:
                th.join(timeout=2.0)
            if self._conn is not None:
                self._conn.close()
                self._conn = None
        if self.error is not None:
            raise self.error
        return finished

    def utc_now(self) -> float:
        """UTC unix seconds on the drive's calendar now (the clock an in-process companion should use as its
        wall clock: SYSTEM_TIME and GPS week/ms then agree)."""
        now = self.clock.now()
        start = self.play_start if self.play_start is not None else now
        return self.drive.utc0 + (now - start)

    @property
    def done(self) -> bool:
        return self._done.is_set()

    @property
    def services(self) -> AutopilotServices:
        if self._services is None:
            raise TacoError("simulator not started")
        return self._services

    def _guard(self, fn: Any) -> Any:
        def run() -> None:
            try:
                fn()
            except BaseException as exc:  # noqa: BLE001 - reported by join()
                log.exception("simulator thread %s failed", threading.current_thread().name)
                self.error = exc
                self._stop.set()
                self._done.set()
        return run

    # ------------------------------------------------------------------ sending
    def _send(self, msg: Any) -> None:
        with self._send_lock:
            if self._conn is None:
                return
            try:
                self._conn.mav.send(msg)
            except OSError as exc:  # companion not there yet (ICMP refused): drop, as a radio would
                log.debug("send %s failed: %s", msg.get_type(), exc)
                return
        kind = msg.get_type()
        self.sent_counts[kind] = self.sent_counts.get(kind, 0) + 1

    def _interval(self, msg_id: int) -> float:
        asked = self.services.intervals.get(msg_id)
        if asked is None or asked == 0.0:
            if msg_id == M.MAVLINK_MSG_ID_SIMSTATE and not self.options.pose_stream:
                return -1.0 if asked is None else 0.0  # off until asked for; asked with 0: the data rate
            return DEFAULT_INTERVALS[msg_id]
        return asked

    def _wait_companion(self) -> None:
        deadline = time.monotonic() + self.options.wait_companion_s
        while not self._stop.is_set() and not self._companion_seen.is_set():
            self._send(encode.heartbeat(self._conn.mav))
            if time.monotonic() >= deadline:
                log.warning("no companion HEARTBEAT within %.0f s: playing anyway", self.options.wait_companion_s)
                return
            self._companion_seen.wait(min(0.5, max(0.01, deadline - time.monotonic())))

    def _play(self) -> None:
        self._wait_companion()
        d, opt, mav = self.drive, self.options, self._conn.mav
        if d.t0_autopilot is not None:  # a recording plays on its own autopilot clock (its frames' times)
            self.clock.advance_to(d.t0_autopilot)
        self.play_start = start = self.clock.now()
        if opt.lockstep:
            self.clock.hold()
        due: dict[int, float] = {k: start for k in DEFAULT_INTERVALS}
        end_t = d.t[-1] if opt.duration_s is None else min(d.t[-1], d.t[0] + opt.duration_s)
        for i in range(len(d)):
            if self._stop.is_set() or d.t[i] > end_t:
                break
            T = start + float(d.t[i])
            if opt.lockstep:
                self._lockstep_wait(T)
                self._send_sample(mav, i, T, due)  # data first, then the clock: nothing is "now" unsent
                self.clock.advance_to(T)
            else:
                while not self._stop.is_set() and (w := self.clock.wall_until(T)) > 0:
                    self._stop.wait(min(w, 0.05))
                self._send_sample(mav, i, T, due)
        self.play_end = self.clock.now()
        drain_until = time.monotonic() + opt.drain_s  # lockstep: the clock stays at the drive's end meanwhile,
        while time.monotonic() < drain_until and not self._stop.is_set():  # so the IMU silence is no "stall"
            self._stop.wait(0.05)
        if opt.lockstep:
            self.clock.release()
        self._done.set()

    def _lockstep_wait(self, T: float) -> None:
        """Lockstep: pace at real time until the companion's first GPS_INPUT, then at `speed`, never letting the
        clock run more than `lockstep_lead_s` past its last GPS_INPUT (waiting up to `lockstep_timeout_s` wall for
        the next, or `lockstep_timeout_behind_s` while the companion is still behind after a missed wait)."""
        started = bool(self.monitor.updates)
        pace = (T - self.clock.now()) / (self.options.speed if started else 1.0)  # real time until it produces
        if pace > 0:
            self._stop.wait(pace)
        if not started:
            return
        need = T - self.options.lockstep_lead_s
        timeout = self.options.lockstep_timeout_behind_s if self._lockstep_behind else self.options.lockstep_timeout_s
        deadline = time.monotonic() + timeout
        with self._gps_event:
            while self.monitor.updates[-1].t < need and not self._stop.is_set() and time.monotonic() < deadline:
                # the autopilot clock runs between samples too: let it reach the lead so a companion whose
                # next output falls between two samples can send it
                self.clock.advance_to(min(T, self.monitor.updates[-1].t + self.options.lockstep_lead_s))
                self._gps_event.wait(0.05)
            self._lockstep_behind = self.monitor.updates[-1].t < need
            if self._lockstep_behind:
                self.lockstep_timeouts += 1
                if self.lockstep_timeouts == 1:
                    log.warning("lockstep: the companion sent no GPS_INPUT within %.2f s wall of its due time "
                                "(does it send at >= 5 Hz on this clock?); going on", timeout)
                log.debug("lockstep: no GPS_INPUT since %.2f s (clock %.2f s)", self.monitor.updates[-1].t, T)

    def _send_sample(self, mav: Any, i: int, T: float, due: dict[int, float]) -> None:
        requested = set()
        while self.services.requested:  # MAV_CMD_REQUEST_MESSAGE: once, now (appended by the receiver thread)
            requested.add(self.services.requested.pop(0))
        for msg_id in (M.MAVLINK_MSG_ID_HEARTBEAT, M.MAVLINK_MSG_ID_SYSTEM_TIME, M.MAVLINK_MSG_ID_HOME_POSITION,
                       M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, M.MAVLINK_MSG_ID_GPS_RAW_INT, M.MAVLINK_MSG_ID_GPS2_RAW,
                       M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, *DATA_STREAMS):
            interval = self._interval(msg_id)
            if msg_id not in requested and (interval < 0 or T + 1e-9 < due[msg_id]):
                continue
            if interval >= 0 and T + 1e-9 >= due[msg_id]:
                due[msg_id] = max(due[msg_id] + interval, T) if interval > 0 else T
            msg = self._message(mav, msg_id, i, T)
            if msg is not None:
                self._send(msg)

    def _message(self, mav: Any, msg_id: int, i: int, T: float) -> Any:
        """Message `msg_id` for drive sample i at autopilot time T (s); None when this autopilot has none."""
        d = self.drive
        if msg_id == M.MAVLINK_MSG_ID_HEARTBEAT:
            return encode.heartbeat(mav)
        if msg_id == M.MAVLINK_MSG_ID_SYSTEM_TIME:
            return encode.system_time(mav, d.utc0 + float(d.t[i]), T)
        if msg_id in (M.MAVLINK_MSG_ID_HOME_POSITION, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN):
            if not self.options.send_home:
                return None
            build = encode.home_position if msg_id == M.MAVLINK_MSG_ID_HOME_POSITION else encode.gps_global_origin
            return build(mav, *self.home, T)
        if msg_id in (M.MAVLINK_MSG_ID_GPS_RAW_INT, M.MAVLINK_MSG_ID_GPS2_RAW):
            instance = 1 if msg_id == M.MAVLINK_MSG_ID_GPS_RAW_INT else 2
            gps_type = self.options.gps_types[instance - 1]
            if gps_type == 0 and instance == 2:
                return None  # ArduPilot sends GPS2_RAW only when a second GPS is configured
            if gps_type == GPS_TYPE_MAV:
                return gps_message(mav, instance, T, self.echo.state())
            return gps_message(mav, instance, T, self.receiver.state(i))
        if msg_id == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return encode.global_position_int(mav, self._believed(i, T), T)
        if msg_id == M.MAVLINK_MSG_ID_RAW_IMU:
            return encode.raw_imu(mav, d, i, T)
        if msg_id == M.MAVLINK_MSG_ID_SCALED_IMU:
            return encode.scaled_imu(mav, d, i, T)
        if msg_id == M.MAVLINK_MSG_ID_HIGHRES_IMU:
            return encode.highres_imu(mav, d, i, T)
        if msg_id == M.MAVLINK_MSG_ID_ATTITUDE:
            return encode.attitude(mav, d, i, T)
        return encode.simstate(mav, d, i)

    def _believed(self, i: int, T: float) -> GnssState | None:
        """Where this autopilot's EKF puts the vehicle at sample i: what it fuses, the companion's last kept
        GPS_INPUT, else a real receiver's fix, else its origin (home) at rest; None before it has any."""
        echo = self.echo.state()
        if echo.fix_type >= GPS_FIX_TYPE_3D_FIX:  # dead-reckoned on at its velocity (at most 10 s)
            dt = min(max(T - self._echo_t, 0.0), 10.0)
            dlat = echo.vn * dt / M_PER_DEG
            dlon = echo.ve * dt / (M_PER_DEG * math.cos(math.radians(echo.lat)))
            return dataclasses.replace(echo, lat=echo.lat + dlat, lon=echo.lon + dlon)
        if any(t not in (0, GPS_TYPE_MAV) for t in self.options.gps_types):  # a real receiver is configured
            real = self.receiver.state(i)
            if real.fix_type >= GPS_FIX_TYPE_3D_FIX:
                return real
        if not self.options.send_home:
            return None
        return GnssState(GPS_FIX_TYPE_3D_FIX, *self.home)

    # ------------------------------------------------------------------ receiving
    def _receive(self) -> None:
        ours = (self.options.sysid, self.options.compid)
        while not self._stop.is_set() or not self._done.is_set():
            conn = self._conn
            if conn is None:
                return
            try:
                msg = conn.recv_match(blocking=True, timeout=0.05)
            except OSError as exc:
                log.debug("receive: %s", exc)
                time.sleep(0.01)
                continue
            if msg is None:
                if self._done.is_set():
                    return
                continue
            if (msg.get_srcSystem(), msg.get_srcComponent()) == ours or msg.get_type() == "BAD_DATA":
                continue
            self._dispatch(msg)

    def _dispatch(self, msg: Any) -> None:
        kind = msg.get_type()
        now = self.clock.now()
        if kind == "HEARTBEAT":
            if self.companion is None:
                self.companion = (msg.get_srcSystem(), msg.get_srcComponent())
                log.info("companion %d/%d heard", *self.companion)
            self._companion_seen.set()
        elif kind == "GPS_INPUT":
            if self.play_start is None:
                return  # before playback: no truth to score against
            with self._gps_event:
                if self.monitor.handle(msg, now) is not None:
                    self.echo.on_gps_input(msg)  # the type-14 instance now reports it
                    self._echo_t = now
                self._gps_event.notify_all()
        elif kind == "STATUSTEXT":
            text = msg.text.decode("ascii", "replace") if isinstance(msg.text, bytes) else str(msg.text)
            self.statustexts.append((now, int(msg.severity), text.rstrip("\x00")))
            log.debug("companion says: %s", text)
        for reply in self.services.handle(msg, now):
            self._send(reply)

    # ------------------------------------------------------------------ results
    @property
    def denied_from_s(self) -> float | None:
        """Drive time (s) from which the real receiver is denied or spoofed; None when it never is."""
        o = self.options
        starts = [t for t in (o.deny_after_s, o.spoof_after_s) if t is not None and t < float(self.drive.t[-1])]
        return float(min(starts)) if starts else None

    def results(self) -> dict[str, Any]:
        """The results.json document of what was played so far (see score.py for the fields)."""
        from taco_mav.sim.score import results_document, score_updates

        start = self.play_start if self.play_start is not None else self.clock.now()
        end = self.play_end if self.play_end is not None else self.clock.now()
        seq = score_updates(self.drive, self.monitor.updates, start, end, self.denied_from_s)
        seq.update(self.monitor.summary(end_t=end, start_t=min(start + self.options.score_from_s, end)))
        seq.update(played_s=max(0.0, end - start), lockstep_timeouts=self.lockstep_timeouts,
                   statustext=[t for _, _, t in self.statustexts[-20:]],
                   not_measured=["ate_imu_only_m", "ate_smoothed_m", "steady_rmse_m", "fixes_per_km", "attempts",
                                 "accepted", "camera_duty_cycle"])
        config = {"simulator": {**asdict(self.options), "drive": str(self.drive.path), "connect": self.connect},
                  "params_set": self.services.param_sets if self._services else [],
                  "messages_sent": dict(self.sent_counts)}
        return results_document({self.drive.name: seq}, config)
