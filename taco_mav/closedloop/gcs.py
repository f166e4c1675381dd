"""The harness's ground station: its own MAVLink link to the autopilot (commands, parameters, a log of all it
receives, mission upload), and the steps every closed-loop mission takes through it: the EKF origin from the
ground station, waiting for the EKF's position, arming, and stopping a runaway. ArduPilot's link is TCP
(`Gcs`); PX4's is UDP (`taco_mav.closedloop.px4_sitl.Px4Gcs`)."""

from __future__ import annotations

import math
import os
import struct
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from taco_mav.closedloop.geometry import metres_between, offset, square_corners  # noqa: E402

M = mavutil.mavlink


class Gcs:
    """The harness's own MAVLink link to SITL (SERIAL0), as a ground station. The generic part (commands,
    parameters, the receive log, mission upload) serves PX4 too (`px4_sitl.Px4Gcs`, which connects over UDP).
    `heartbeat_s`: send a GCS HEARTBEAT this often while pumping (None: never; ArduPilot talks to anyone on TCP)."""

    heartbeat_s: float | None = None

    def __init__(self, port: int) -> None:
        deadline = time.time() + 60
        while True:
            try:
                m = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=250, source_component=190,
                                               autoreconnect=False)
                break
            except OSError:
                if time.time() > deadline:
                    raise
                time.sleep(0.5)
        m.wait_heartbeat(timeout=60)
        self._attach(m)

    def _attach(self, m: Any) -> None:
        """Use connection `m`, whose autopilot heartbeat has been seen (m.target_system set)."""
        self.m = m
        self.target = (self.m.target_system, M.MAV_COMP_ID_AUTOPILOT1)
        self.log: list[tuple[float, Any]] = []
        self.texts: list[tuple[float, int, str]] = []
        self._heartbeat_at = 0.0

    def send_cmd(self, cmd: int, *p: float) -> None:
        args = list(p) + [0.0] * (7 - len(p))
        self.m.mav.command_long_send(*self.target, cmd, 0, *args)

    def interval(self, msg_id: int, hz: float) -> None:
        self.send_cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)

    def heartbeat(self) -> None:
        self.m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self._heartbeat_at = time.time()

    def set_param(self, name: str, value: float, param_type: int = M.MAV_PARAM_TYPE_REAL32) -> None:
        """PARAM_SET until PARAM_VALUE echoes `value`. REAL32 sends the value as a float (ArduPilot casts it);
        INT32 packs the integer's bytes into the float (PX4's bytewise encoding) and reads the answer back the
        same way."""
        if param_type == M.MAV_PARAM_TYPE_INT32:
            wire = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        else:
            wire = float(value)
        for _ in range(5):
            self.m.mav.param_set_send(*self.target, name.encode(), wire, param_type)
            got = self.m.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
            while got is not None and got.param_id != name:
                got = self.m.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
            if got is None:
                continue
            now = got.param_value
            if param_type == M.MAV_PARAM_TYPE_INT32 and got.param_type == M.MAV_PARAM_TYPE_INT32:
                now = struct.unpack("<i", struct.pack("<f", got.param_value))[0]
            if abs(now - value) < 1e-3 * max(1.0, abs(value)):
                return
        raise RuntimeError(f"SITL did not take {name}={value}")

    def pump(self, seconds: float) -> list[Any]:
        """Receive for `seconds` (wall), keeping every message with its wall time."""
        out = []
        end = time.time() + seconds
        while time.time() < end:
            if self.heartbeat_s is not None and time.time() - self._heartbeat_at >= self.heartbeat_s:
                self.heartbeat()
            wait = end - time.time()
            if self.heartbeat_s is not None:
                wait = min(wait, self.heartbeat_s)
            msg = self.m.recv_match(blocking=True, timeout=max(0.0, wait))
            if msg is None:
                continue
            now = time.time()
            self.log.append((now, msg))
            if msg.get_type() == "STATUSTEXT":
                self.texts.append((now, msg.severity, msg.text))
            out.append(msg)
        return out

    def write_tlog(self, path: Path) -> None:
        """Everything received, as a tlog (8-byte big-endian UNIX microseconds before each message), for
        mavlogdump.py / MAVExplorer."""
        with open(path, "wb") as f:
            for t, msg in self.log:
                f.write(struct.pack(">Q", int(t * 1e6)) + msg.get_msgbuf())

    def upload_square(self, home: tuple[float, float, float, float], side: float, laps: int, home_item: bool = True,
                      frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, alt: float = 0.0) -> int:
        """`_upload_square`, retried: just after boot ArduPilot answers NO_SPACE until its storage is up."""
        for attempt in range(20):
            try:
                return self._upload_square(home, side, laps, home_item, frame, alt)
            except RuntimeError as e:
                if attempt == 19 or "type : 4" not in str(e):
                    raise
                self.pump(2.0)
        raise AssertionError("unreachable")

    def _upload_square(self, home: tuple[float, float, float, float], side: float, laps: int, home_item: bool = True,
                       frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, alt: float = 0.0) -> int:
        """A square of `side` metres (N, E, S, W legs) from home, `laps` times, then HOLD at home; returns the
        number of mission items. home_item: item 0 is home, as ArduPilot expects (PX4: item 0 is the first
        waypoint). frame and alt (metres in that frame) go on every item."""
        lat0, lon0 = home[0], home[1]
        corners = square_corners(side)
        wps = [offset(lat0, lon0, e, n) for _ in range(laps) for e, n in corners]
        items = ([(lat0, lon0, M.MAV_CMD_NAV_WAYPOINT)] if home_item else []) + \
            [(la, lo, M.MAV_CMD_NAV_WAYPOINT) for la, lo in wps]
        self.m.mav.mission_clear_all_send(*self.target)
        time.sleep(0.5)
        self.m.mav.mission_count_send(*self.target, len(items), 0)
        sent: set[int] = set()
        deadline = time.time() + 30
        while time.time() < deadline:
            msg = self.m.recv_match(type=["MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"], blocking=True,
                                    timeout=5)
            if msg is None:
                continue
            if msg.get_type() == "MISSION_ACK":
                if msg.type != M.MAV_MISSION_ACCEPTED:
                    raise RuntimeError(f"mission upload refused: {msg}")
                if len(sent) == len(items):
                    return len(items)
                continue  # the answer to the clear
            la, lo, cmd = items[msg.seq]
            self.m.mav.mission_item_int_send(*self.target, msg.seq, frame, cmd,
                                             0, 1, 0, 0, 0, 0, int(la * 1e7), int(lo * 1e7), alt, 0)
            sent.add(msg.seq)
        raise RuntimeError("mission upload timed out")



def set_ekf_origin(gcs: Gcs, home: tuple[float, float, float, float], limit_s: float = 90.0) -> float:
    """SET_GPS_GLOBAL_ORIGIN every 2 s until the autopilot reports GPS_GLOBAL_ORIGIN (its EKF takes it only
    once it runs); returns the wall seconds it took."""
    t0 = time.time()
    while time.time() - t0 < limit_s:
        gcs.m.mav.set_gps_global_origin_send(gcs.target[0], int(home[0] * 1e7), int(home[1] * 1e7), int(home[2] * 1e3),
                                             int(time.time() * 1e6))
        gcs.send_cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)
        if any(m.get_type() == "GPS_GLOBAL_ORIGIN" for m in gcs.pump(2.0)):
            return time.time() - t0
    raise RuntimeError("the autopilot never took the EKF origin (SET_GPS_GLOBAL_ORIGIN)")


def wait_ekf(gcs: Gcs, limit_s: float, status_kind: str = "EKF_STATUS_REPORT", need_global: bool = False,
             refuse: int = M.EKF_CONST_POS_MODE, settle_s: float = 5.0) -> float | None:
    """Wall time at which the EKF reports an absolute horizontal position and none of the `refuse` flags
    (flags of `status_kind`: ArduPilot's EKF_STATUS_REPORT and PX4's ESTIMATOR_STATUS use the same bits; PX4
    sets CONST_POS_MODE whenever the vehicle is at rest, so it passes refuse=0), then settle_s of settling; with
    need_global, the latest GLOBAL_POSITION_INT must also be non-zero. None after limit_s."""
    end = time.time() + limit_s
    have_global = not need_global
    while time.time() < end:
        for msg in gcs.pump(0.5):
            if msg.get_type() == "GLOBAL_POSITION_INT" and need_global:
                have_global = msg.lat != 0 or msg.lon != 0
            if msg.get_type() == status_kind and msg.flags & M.EKF_POS_HORIZ_ABS and \
                    not msg.flags & refuse and have_global:
                gcs.pump(settle_s)
                return time.time()
    return None


def arm(gcs: Gcs) -> float:
    """MAV_CMD_COMPONENT_ARM_DISARM once a second until the autopilot's HEARTBEAT says armed (30 tries);
    returns the wall time, or raises with the autopilot's last STATUSTEXTs."""
    for _ in range(30):
        gcs.send_cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        for msg in gcs.pump(1.0):
            if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == gcs.target[0] and \
                    msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
                return time.time()
    raise RuntimeError("SITL refused to arm: " + "; ".join(t for _, _, t in gcs.texts[-5:]))


def runaway(gcs: Gcs, spec: Any, *, hold: tuple[float, ...], truth_kind: str = "SIMSTATE",
            truth_lon: str = "lng") -> bool:
    """Truth (the latest `truth_kind`, lat and `truth_lon` in degE7; ArduPilot's SIMSTATE by default) more than
    3 spec.side_m from spec.home: stop early (MAV_CMD_DO_SET_MODE with `hold`, the autopilot's HOLD: ArduPilot's
    `ardupilot.MODE_HOLD`, PX4's `px4_sitl.MODE_HOLD`), the run has failed anyway."""
    for _, msg in reversed(gcs.log[-50:]):
        if msg.get_type() == truth_kind:
            e, n = metres_between(spec.home[0], spec.home[1], msg.lat * 1e-7, getattr(msg, truth_lon) * 1e-7)
            if math.hypot(e, n) > 3 * spec.side_m:
                gcs.send_cmd(M.MAV_CMD_DO_SET_MODE, *hold)
                return True
            return False
    return False

