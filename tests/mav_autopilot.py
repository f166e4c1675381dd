"""A minimal MAVLink autopilot for link tests: a real pymavlink endpoint on 127.0.0.1 that drives a straight,
constant-speed, level rover and records what the daemon sends back.

Sends HEARTBEAT 1 Hz, GPS2_RAW (3D fix: a real receiver as GPS2, since GPS1 is the daemon's GPS_INPUT) for the
first second, RAW_IMU at `imu_hz` (level at rest: zacc -1000 mG), ATTITUDE at `att_hz`, SYSTEM_TIME 1 Hz,
SIMSTATE (the true pose) at 10 Hz; answers PARAM_REQUEST_READ (GPS1_TYPE = `gps1_type`, and any name in `params`),
COMMAND_LONG (ACK accepted) and TIMESYNC.
Truth: start (lat0, lon0), heading `yaw_deg` (NED, true), speed `speed` m/s; autopilot time = boot_s + elapsed.

`flavour="px4"` speaks as PX4 SIH does instead: HEARTBEAT autopilot MAV_AUTOPILOT_PX4, HIGHRES_IMU (SI units),
HIL_STATE_QUATERNION as the true pose (only once asked for, as PX4 streams it), no GPS2_RAW.

Faults: `stall` silences IMU/ATTITUDE; `streams_reset_at` (elapsed s) drops RAW_IMU to 1 Hz, as a ground
station's REQUEST_DATA_STREAM on the same port does to ArduPilot, until a SET_MESSAGE_INTERVAL for RAW_IMU comes
after it; `outage` closes the connection for a while (nothing sent or read; the
vehicle drives on) and reopens it (UDP: a new socket, `udp_local_port` keeps the source port or not; TCP: the
autopilot is the server, `transport="tcp"`, and closes and reopens its listening socket); `reboot_at` restarts
the autopilot clock.
"""

from __future__ import annotations

import math
import os
import socket
import threading
import time
from dataclasses import dataclass, field

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from taco_mav.config import Profile, profile_from_dict  # noqa: E402
from taco_mav.geo import UtmProjector  # noqa: E402
from taco_mav.mavlink.connection import free_udp_port  # noqa: E402,F401 (re-exported for the tests)

m = mavutil.mavlink

# FG2's failure modes off (tests/test_emulator.py and tests/test_honesty.py test them). The emulator seeds each draw
# with the frame time in ms, and a link test's frame times follow the wall clock: with the modes on, 1 frame time in
# 25 or so is a silent outlier or a symmetric lock (4.5 % of draws at seed 0), which the daemon rightly accepts or
# rejects and reports as a 13 m accuracy and fix type 1 for a couple of seconds (in test_daemon.py a check frame at
# t = 100.81 s draws a 12.9 m silent outlier). A link test asserts what the link carries, so its matcher answers
# with FG2's nominal error only.
STEADY_EMULATOR = {"symmetric_lock_rate": 0.0, "silent_outlier_rate": 0.0}


def link_test_profile(extra: dict[str, object] | None = None) -> Profile:
    """The default profile with the emulator matcher at FG2's nominal error (`STEADY_EMULATOR`); `extra`: further
    top-level profile sections (an "emulator" section is merged over the steady one)."""
    extra = dict(extra or {})
    emulator = {**STEADY_EMULATOR, **extra.pop("emulator", {})}
    return profile_from_dict({"matcher": "emulator", "emulator": emulator, **extra})


@dataclass
class Received:
    t: float  # monotonic arrival
    msg: object


@dataclass
class MiniAutopilot:
    port: int
    lat0: float = 49.0
    lon0: float = 8.4
    alt0: float = 115.0
    yaw_deg: float = 30.0
    speed: float = 5.0
    imu_hz: float = 100.0
    att_hz: float = 50.0
    boot_s: float = 100.0
    gps1_type: int = 14
    flavour: str = "ardupilot"  # or "px4" (see the module docstring)
    send_simstate: bool = True
    stall: tuple[float, float] | None = None  # (from, to) elapsed s: no IMU/ATTITUDE (inputs stall)
    reboot_at: float | None = None  # elapsed s: the autopilot clock restarts at 1 s (a reboot)
    outage: tuple[float, float] | None = None  # (from, to) elapsed s: connection closed, nothing sent or read
    streams_reset_at: float | None = None  # elapsed s: RAW_IMU at 1 Hz from then until asked for again
    imu_asked_again_at: float | None = None  # elapsed s of the first SET_MESSAGE_INTERVAL RAW_IMU after the reset
    port_defaults_until: float | None = None  # elapsed s: RAW_IMU at 0.5 Hz until then (its grant comes late), and
    # SCALED_IMU2 at 2 Hz throughout (ArduPilot's SRn_RAW_SENS sends it beside RAW_IMU at 1-4 Hz)
    transport: str = "udp"  # "udp": udpout to the daemon's udpin; "tcp": a server on `port` (daemon: tcp:)
    udp_local_port: int | None = None  # UDP source port (None: ephemeral, a new one after an outage)
    gps_s: float = 1.0  # GPS2_RAW (3D fix, 4 Hz) for this long after start (GPS1 is the daemon's GPS_INPUT)
    received: list[Received] = field(default_factory=list)
    params_asked: list[str] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)  # further parameters answered (e.g. GPS1_POS_X)
    commands: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.conn = self._open()
        self.proj = UtmProjector.for_latlon(self.lat0, self.lon0)
        self.e0, self.n0 = self.proj.to_utm(self.lat0, self.lon0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.t_start = 0.0

    def _open(self):
        """A fresh connection: udpout (optionally from a fixed source port) or a TCP server."""
        if self.transport == "tcp":
            return mavutil.mavlink_connection(f"tcpin:127.0.0.1:{self.port}", source_system=1, source_component=1,
                                              dialect="ardupilotmega")
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.port}", source_system=1, source_component=1,
                                          dialect="ardupilotmega")
        if self.udp_local_port is not None:
            conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            conn.port.bind(("127.0.0.1", self.udp_local_port))
        return conn

    # truth ------------------------------------------------------------
    def truth_latlon(self, elapsed: float) -> tuple[float, float]:
        """True position after `elapsed` seconds (the straight line is on the true-north frame)."""
        d = self.speed * elapsed
        psi = math.radians(self.yaw_deg)
        # metres north/east on the UTM grid: rotate the true course by the convergence
        conv = float(self.proj.grid_convergence(self.lat0, self.lon0))
        theta_grid = math.pi / 2 - psi + conv
        lat, lon = self.proj.to_latlon(self.e0 + d * math.cos(theta_grid), self.n0 + d * math.sin(theta_grid))
        return float(lat), float(lon)

    def ap_time(self, el: float) -> float:
        """Autopilot clock, s, at `el` seconds after start (restarts at 1 s on a reboot)."""
        if self.reboot_at is not None and el >= self.reboot_at:
            return 1.0 + el - self.reboot_at
        return self.boot_s + el

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        if self.conn is not None:
            self.conn.close()

    def _in_outage(self, el: float) -> bool:
        """Close the connection at the outage start, reopen it at its end; True while it is closed."""
        out = self.outage is not None and self.outage[0] <= el < self.outage[1]
        if out and self.conn is not None:
            self.conn.close()
            self.conn = None
        elif not out and self.conn is None:
            self.conn = self._open()
        return out

    def _run(self) -> None:
        mav = self.conn.mav
        self.t_start = time.monotonic()
        k_imu = k_att = k_sim = 0
        next_hb = next_st = 0.0
        while not self._stop.is_set():
            el = time.monotonic() - self.t_start
            t_ap = self.ap_time(el)
            if self._in_outage(el):  # the vehicle drives on; nothing is sent, nothing queued for later
                k_imu, k_att, k_sim = (int(el * r) + 1 for r in (self.imu_hz, self.att_hz, 10.0))
                next_hb, next_st = math.floor(el) + 1.0, math.floor(el) + 1.0
                time.sleep(0.002)
                continue
            mav = self.conn.mav
            stalled = self.stall is not None and self.stall[0] <= el < self.stall[1]
            if el >= next_hb:
                kind = m.MAV_AUTOPILOT_PX4 if self.flavour == "px4" else m.MAV_AUTOPILOT_ARDUPILOTMEGA
                mav.heartbeat_send(m.MAV_TYPE_GROUND_ROVER, kind, 0, 0, m.MAV_STATE_ACTIVE)
                next_hb += 1.0
            if el >= next_st:
                mav.system_time_send(int(time.time() * 1e6), int(t_ap * 1e3))
                if el < self.gps_s and self.flavour != "px4":
                    lat, lon = self.truth_latlon(el)
                    mav.gps2_raw_send(int(t_ap * 1e6), 3, int(lat * 1e7), int(lon * 1e7), int(self.alt0 * 1e3),
                                      80, 120, int(self.speed * 100), int(self.yaw_deg * 100), 12, 0, 0)
                next_st += 0.25 if el < self.gps_s else 1.0
            while k_att / self.att_hz <= el:
                if not stalled:
                    mav.attitude_send(int(t_ap * 1e3), 0.0, 0.0, math.radians(self.yaw_deg), 0.0, 0.0, 0.0)
                k_att += 1
            slow = self.streams_reset_at is not None and el >= self.streams_reset_at and \
                self.imu_asked_again_at is None
            defaults = self.port_defaults_until is not None and el < self.port_defaults_until
            while k_imu / self.imu_hz <= el:
                every = 2 * int(self.imu_hz) if defaults else int(self.imu_hz) if slow else 1  # 0.5 Hz, 1 Hz
                half = int(self.imu_hz) // 2
                if self.port_defaults_until is not None and not stalled and k_imu % half == half // 2:  # 2 Hz
                    mav.scaled_imu2_send(int(self.ap_time(k_imu / self.imu_hz) * 1e3), 0, 0, -1000, 0, 0, 0, 0, 0, 0)
                if k_imu % every:
                    k_imu += 1
                    continue
                if not stalled and self.flavour == "px4":
                    mav.highres_imu_send(int(self.ap_time(k_imu / self.imu_hz) * 1e6), 0, 0, -9.80665, 0, 0, 0,
                                         0, 0, 0, 0, 0, 0, 0, 0b111111)
                elif not stalled:
                    mav.raw_imu_send(int(self.ap_time(k_imu / self.imu_hz) * 1e6), 0, 0, -1000, 0, 0, 0, 0, 0, 0)
                k_imu += 1
            if self.send_simstate and k_sim / 10.0 <= el:
                lat, lon = self.truth_latlon(el)
                if self.flavour != "px4":
                    mav.simstate_send(0.0, 0.0, math.radians(self.yaw_deg), 0, 0, -9.8, 0, 0, 0, int(lat * 1e7),
                                      int(lon * 1e7))
                elif m.MAVLINK_MSG_ID_HIL_STATE_QUATERNION in self.commands:  # PX4 streams it when asked
                    half = math.radians(self.yaw_deg) / 2
                    mav.hil_state_quaternion_send(0, [math.cos(half), 0, 0, math.sin(half)], 0, 0, 0, int(lat * 1e7),
                                                  int(lon * 1e7), int(self.alt0 * 1e3), 0, 0, 0, 0, 0, 0, 0, 0)
                k_sim += 1
            self._answer()
            time.sleep(0.002)

    def _answer(self) -> None:
        mav = self.conn.mav
        while True:
            msg = self.conn.recv_msg()
            if msg is None:
                return
            kind = msg.get_type()
            self.received.append(Received(time.monotonic(), msg))
            if kind == "PARAM_REQUEST_READ":
                name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
                self.params_asked.append(name)
                if name == "GPS1_TYPE":
                    mav.param_value_send(b"GPS1_TYPE", float(self.gps1_type), m.MAV_PARAM_TYPE_INT8, 900, 1)
                elif name in self.params:
                    mav.param_value_send(name.encode(), float(self.params[name]), m.MAV_PARAM_TYPE_REAL32, 900, 1)
            elif kind == "COMMAND_LONG":
                self.commands.append(int(msg.param1))
                el = time.monotonic() - self.t_start
                if msg.command == m.MAV_CMD_SET_MESSAGE_INTERVAL and int(msg.param1) == m.MAVLINK_MSG_ID_RAW_IMU and \
                        self.streams_reset_at is not None and el >= self.streams_reset_at and \
                        self.imu_asked_again_at is None:
                    self.imu_asked_again_at = el
                mav.command_ack_send(msg.command, m.MAV_RESULT_ACCEPTED)
            elif kind == "TIMESYNC" and msg.tc1 == 0:
                mav.timesync_send(int(self.ap_time(time.monotonic() - self.t_start) * 1e9), msg.ts1)

    def of_type(self, kind: str) -> list[Received]:
        return [r for r in self.received if r.msg.get_type() == kind]
