"""Helpers for the simulator tests: a free loopback UDP port and a minimal companion that echoes the
simulator's SIMSTATE pose back as GPS_INPUT (a perfect localiser), paced on the simulator's clock;
`write_tlog`: a drive written as the tlog a GNSS-on recording would be; `play`: a simulator played to an in-process
daemon to its end."""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any, Callable, Sequence

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as apm  # noqa: E402

from taco_mav.geo import gps_week_ms  # noqa: E402
from taco_mav.mavlink.connection import free_udp_port  # noqa: E402,F401 (re-exported for the tests)
from taco_mav.mavlink.tlog import TlogWriter  # noqa: E402
from taco_mav.sim import encode  # noqa: E402
from taco_mav.sim.source import SimDrive  # noqa: E402

BOOT, UTC = 100.0, 1.7e9  # write_tlog: autopilot seconds at drive time 0, UTC unix seconds at drive time 0


class EchoCompanion:
    """Listens on udpin:127.0.0.1:port, answers with HEARTBEATs, asks for GPS1_TYPE, SET_MESSAGE_INTERVAL
    and TIMESYNC once, and sends GPS_INPUT every `period_s` of `clock` (the simulator's clock) at the last
    SIMSTATE position plus `offset_deg` (lat, lon degrees). `stall_at` (autopilot s since its first GPS_INPUT,
    wall s): at that time the companion sleeps that many wall seconds (a stalled process); wall s None: it
    never sends again."""

    def __init__(self, port: int, clock: Callable[[], float], period_s: float = 0.2, gps_id: int = 0,
                 offset_deg: tuple[float, float] = (0.0, 0.0), h_acc: float = 1.0,
                 stall_at: tuple[float, float | None] | None = None) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=191,
                                               dialect="ardupilotmega")
        self.clock, self.period_s, self.gps_id = clock, period_s, gps_id
        self.offset_deg, self.h_acc, self.stall_at = offset_deg, h_acc, stall_at
        self.received: dict[str, list[Any]] = {}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> "EchoCompanion":
        self.thread.start()
        return self

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=2.0)
        self.conn.close()

    def _run(self) -> None:
        mav = self.conn.mav
        asked = False
        next_out = None
        utc = None
        while not self.stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.002)
            if msg is not None and msg.get_type() != "BAD_DATA":
                self.received.setdefault(msg.get_type(), []).append(msg)
                if msg.get_type() == "SYSTEM_TIME":
                    utc = (msg.time_unix_usec * 1e-6, msg.time_boot_ms * 1e-3)
                if not asked and msg.get_type() == "HEARTBEAT":
                    asked = True
                    mav.heartbeat_send(18, 8, 0, 0, 4)  # MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID
                    mav.param_request_read_send(1, 1, b"GPS1_TYPE", -1)
                    mav.command_long_send(1, 1, 511, 0, mavutil.mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, 100000,
                                          0, 0, 0, 0, 0)
                    mav.command_long_send(1, 1, 511, 0, 99999, 100000, 0, 0, 0, 0, 0)
                    mav.timesync_send(0, 123456789)
            states = self.received.get("SIMSTATE")
            if not states:
                continue
            now = self.clock()
            if next_out is None:
                next_out = first = now
            if self.stall_at is not None and now - first >= self.stall_at[0]:
                if self.stall_at[1] is None:
                    continue
                self.stop.wait(self.stall_at[1])
                self.stall_at = None
            if now >= next_out:
                next_out += self.period_s
                s = states[-1]
                week, ms = gps_week_ms(utc[0] + now - utc[1]) if utc else (0, 0)
                mav.gps_input_send(0, self.gps_id, 0, ms, week, 3,
                                   s.lat + int(round(self.offset_deg[0] * 1e7)),
                                   s.lng + int(round(self.offset_deg[1] * 1e7)), 100.0, 0.8, 0.8, 0.0, 0.0, 0.0,
                                   0.3, self.h_acc, 1.0, 10, 0)


def write_tlog(path: Path, d: SimDrive, gps_every: int = 2, gps_latency_s: float | Sequence[float] = 0.1,
               fix: bool = True, radio_delay_s: float = 0.02, gps_clock_s: float = 0.0) -> Path:
    """RAW_IMU and ATTITUDE at every sample, GPS_RAW_INT every `gps_every` samples (its receive time
    `gps_latency_s` later than the IMU's: one value, or one per fix); autopilot time BOOT + t, receive time
    UTC + t + radio_delay_s; the fixes' own time (time_usec) BOOT + t + gps_clock_s (another clock than the IMU's
    when not 0)."""
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    log = TlogWriter(path)
    for i in range(len(d)):
        T, rx = BOOT + float(d.t[i]), UTC + float(d.t[i]) + radio_delay_s
        log.write(encode.heartbeat(mav).pack(mav), rx)
        log.write(encode.raw_imu(mav, d, i, T).pack(mav), rx)
        log.write(encode.attitude(mav, d, i, T).pack(mav), rx)
        if i % gps_every == 0:
            lag = gps_latency_s if isinstance(gps_latency_s, (int, float)) else gps_latency_s[i // gps_every]
            log.write(encode.gps_raw_int(mav, d, i, T + gps_clock_s, fix=fix).pack(mav), rx + float(lag))
    log.close()
    return path


def play(sim: Any, daemon: Any, timeout_s: float = 120.0) -> None:
    """Start `daemon` (taco_mav.daemon.Daemon) and `sim` (taco_mav.sim.Simulator), wait for the drive's end, stop
    the daemon (also when the simulator fails)."""
    daemon.start()
    try:
        sim.start()
        assert sim.join(timeout=timeout_s), "simulator did not finish"
    finally:
        daemon.stop()
        daemon.join(5.0)
