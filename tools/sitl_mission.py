#!/usr/bin/env python3
"""Closed loop on a real autopilot: ArduPilot Rover SITL driven by taco-mav (issue 19).

Starts `ardurover` (built by ../shared/tools/build_ardupilot_sitl.sh) on free TCP ports, the daemon
(`taco-mav run`, a subprocess exactly as a user starts it) on SITL's SERIAL1 with a camera rendered from a
synthetic world centred on SITL's home, uploads a square mission, arms, drives in AUTO and scores:
- the EKF's position (GLOBAL_POSITION_INT) against SITL's truth (SIMSTATE), metres;
- the rover's true speed (differentiated SIMSTATE) against WP_SPEED, m/s;
- our own output (the GPS instance that is ours, GPS_RAW_INT or GPS2_RAW) against the truth, with the
  horizontal accuracy we reported beside it (never again 1.2 m reported at 53 m).

Set-ups: `solo` (GPS1_TYPE=14: taco-mav is the only GPS) and `handover` (SITL's GNSS is GPS1 and steers the rover,
taco-mav is GPS2 with GPS2_TYPE=14; SIM_GPS1_ENABLE=0 part-way through the mission, so the EKF falls over to us).

    python tools/sitl_mission.py --ardurover $ARDUROVER --out /tmp/sitl1 [--setup handover] [--estimator paper]

Writes OUT/result.json (the figures), OUT/truth.csv, ekf_error.csv, ours_error.csv, gcs.tlog (all the ground station
heard), the daemon's tlog and events in OUT/daemon/<UTC start time>/, and OUT/sitl/ (SITL's own files). Nothing
here is product code: tests/test_sitl.py runs it when ARDUROVER is set.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
import numpy as np  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from taco_mav.daemon.eventlog import read_events  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sitl_faults import KINDS as FAULT_KINDS  # noqa: E402
from sitl_faults import FaultRun  # noqa: E402

M = mavutil.mavlink
HOME = (-35.363261, 149.165230, 584.0, 0.0)  # SITL's default (CMAC), lat, lon, alt m, heading deg
ROVER_AUTO, ROVER_HOLD = 10, 4
ROOT = Path(__file__).resolve().parents[1]


@dataclass
class MissionSpec:
    """What to fly. side_m: square side, metres (first leg north from home); laps; wp_speed: WP_SPEED m/s;
    setup: solo | handover; gnss_off_after_s: handover only, seconds after AUTO when SIM_GPS1_ENABLE=0;
    timeout_s: wall seconds allowed for the mission after AUTO."""

    side_m: float = 60.0
    laps: int = 2
    wp_speed: float = 3.0
    setup: str = "solo"
    gnss_off_after_s: float = 30.0
    estimator: str = "taco+"
    profile: str = "ardupilot_rover"
    world_seed: int = 7
    timeout_s: float = 300.0
    ekf_wait_s: float = 150.0
    home: tuple[float, float, float, float] = HOME
    extra_params: dict[str, float] = field(default_factory=dict)
    daemon_origin: bool = False  # give the daemon --origin (home) instead of letting it find one
    restart_after_s: float | None = None  # SIGTERM the daemon this long after AUTO and start it again (issue 30)
    daemon_args: tuple[str, ...] = ()  # more `taco-mav run` options (e.g. --record, --shadow)
    fault: str | None = None  # a fault on cue (tools/sitl_faults.py: camera, stall, link, glitch, spoof)
    fault_after_s: float = 60.0  # ... this long after AUTO
    realism: str = "flat"  # the world the camera sees: flat (the mosaic painted on the ground) or 3d (issue 31)
    # the daemon's map is another world's mosaic (this seed) over the same ground: a camera that cannot read the
    # map it is given, every answer wrong (issue 37); None: the world's own map
    map_seed: int | None = None
    # a 3-D world keeps its buildings, trees and cars off the square; False drives the square through them (issue
    # 37: the camera cannot read the ground for long stretches)
    keep_clear: bool = True


def free_instance() -> int:
    """An -I instance whose TCP ports 5760+10I .. 5763+10I and UDP 5501+10I are free."""
    for inst in range(0, 40):
        ok = True
        for port in range(5760 + 10 * inst, 5764 + 10 * inst):
            with socket.socket() as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    ok = False
                    break
        if ok:
            return inst
    raise RuntimeError("no free SITL instance ports")


def metres_between(lat0: float, lon0: float, lat1: float, lon1: float) -> tuple[float, float]:
    """(east, north) metres from point 0 to point 1 (equirectangular; fine over a few hundred metres)."""
    r = 6378137.0
    return (math.radians(lon1 - lon0) * r * math.cos(math.radians(lat0)), math.radians(lat1 - lat0) * r)


def offset(lat: float, lon: float, east: float, north: float) -> tuple[float, float]:
    r = 6378137.0
    return lat + math.degrees(north / r), lon + math.degrees(east / (r * math.cos(math.radians(lat))))


class Gcs:
    """The harness's own MAVLink link to SITL (SERIAL0), as a ground station. The generic part (commands,
    parameters, the receive log, mission upload) serves tools/px4_mission.py too, whose subclass connects over UDP.
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


def _params(spec: MissionSpec) -> dict[str, float]:
    """SITL parameters of the set-up (written to a defaults file, so they hold from boot)."""
    p: dict[str, float] = {"SERIAL1_PROTOCOL": 2, "SERIAL1_BAUD": 921, "WP_SPEED": spec.wp_speed,
                           "CRUISE_SPEED": spec.wp_speed}
    if spec.setup == "solo":
        p.update({"GPS1_TYPE": 14, "GPS2_TYPE": 0, "GPS_AUTO_SWITCH": 0})
    elif spec.setup == "handover":
        p.update({"GPS1_TYPE": 1, "GPS2_TYPE": 14, "GPS_AUTO_SWITCH": 4, "GPS_PRIMARY": 0})
    else:
        raise ValueError(f"setup {spec.setup!r}: solo or handover")
    p.update(spec.extra_params)
    return p


def square_corners(side: float) -> list[tuple[float, float]]:
    """The mission's square from home, (east, north) metres: N, E, S, W legs."""
    return [(0.0, side), (side, side), (side, 0.0), (0.0, 0.0)]


def build_world(out: Path, spec: Any) -> Path:
    """OUT/world, centred on `spec.home` (kept when it is there already, of `spec.realism`). `spec`: a MissionSpec or
    px4_mission's Px4MissionSpec (world_seed, home, side_m, realism). A 3-D world keeps its buildings, trees, poles
    and parked cars off the mission's square (`taco-mav world --keep-clear`), as it keeps them off its own drive:
    SITL has no obstacles, and a real rover would not drive through a house."""
    world = out / "world"
    meta = world / "world.json"
    if meta.exists() and json.loads(meta.read_text()).get("realism", "flat") == spec.realism and spec.keep_clear:
        return world
    cmd = [sys.executable, "-m", "taco_mav.cli", "world", "-q", "--out", str(world), "--seed", str(spec.world_seed),
           "--length-km", "0.6", f"--centre={spec.home[0]},{spec.home[1]}", "--realism", spec.realism, "--force"]
    if spec.realism == "3d" and spec.keep_clear:
        square = [(0.0, 0.0)] + square_corners(spec.side_m)
        cmd.append("--keep-clear=" + ";".join(f"{e:g},{n:g}" for e, n in square))
    subprocess.run(cmd, check=True)
    return world


def run_mission(ardurover: Path, out: Path, spec: MissionSpec, world: Path | None = None) -> dict[str, Any]:
    """Fly `spec` on SITL with taco-mav in the loop; returns the figures (also written to OUT/result.json)."""
    out.mkdir(parents=True, exist_ok=True)
    world = world or build_world(out, spec)
    inst = free_instance()
    sitl_dir = out / "sitl"
    shutil.rmtree(sitl_dir, ignore_errors=True)
    sitl_dir.mkdir()
    defaults = ardurover.resolve().parents[3] / "Tools/autotest/default_params/rover.parm"
    extra = sitl_dir / "taco.parm"
    extra.write_text("".join(f"{k} {v}\n" for k, v in _params(spec).items()))
    home = ",".join(str(v) for v in spec.home)
    sitl = subprocess.Popen([str(ardurover), "--model", "rover", "--speedup", "1", "-I", str(inst), "-w", "--home", home,
                             "--defaults", f"{defaults},{extra}"], cwd=sitl_dir, stdout=open(sitl_dir / "out.log", "w"),
                            stderr=subprocess.STDOUT, start_new_session=True)
    daemon = fault = None
    try:
        gcs = Gcs(5760 + 10 * inst)
        camera, port = f"world:{world}", 5762 + 10 * inst
        wrong_map = []
        if spec.map_seed is not None:
            other = build_world(out / "other", replace(spec, world_seed=spec.map_seed))
            wrong_map = ["--map", str(other / json.loads((other / "world.json").read_text())["mosaic"])]
        if spec.fault is not None:
            fault = FaultRun(spec.fault, spec.fault_after_s, out, gcs, spec.home, spec.setup)
            camera, port = fault.camera(world), fault.connect_port(port)
        daemon_cmd = [sys.executable, "-m", "taco_mav.cli", "run", "--profile", spec.profile, "--connect",
                      f"tcp:127.0.0.1:{port}", "--camera", camera, "--log-dir",
                      str(out / "daemon"), "--estimator", spec.estimator]
        if spec.daemon_origin:
            daemon_cmd.append(f"--origin={spec.home[0]},{spec.home[1]},{spec.home[2]}")
        daemon_cmd += wrong_map + list(spec.daemon_args)
        shutil.rmtree(out / "daemon", ignore_errors=True)
        daemon = subprocess.Popen(daemon_cmd, stdout=open(out / "daemon.log", "w"), stderr=subprocess.STDOUT,
                                  start_new_session=True)
        for mid, hz in ((M.MAVLINK_MSG_ID_SIMSTATE, 10), (M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 10),
                        (M.MAVLINK_MSG_ID_GPS_RAW_INT, 5), (M.MAVLINK_MSG_ID_GPS2_RAW, 5),
                        (M.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 2), (M.MAVLINK_MSG_ID_MISSION_CURRENT, 2),
                        (M.MAVLINK_MSG_ID_VFR_HUD, 5)):
            gcs.interval(mid, hz)
        if spec.setup == "solo":  # no GNSS at all: the ground station sets the EKF origin, as a user would
            set_ekf_origin(gcs, spec.home)
        n_items = gcs.upload_square(spec.home, spec.side_m, spec.laps)
        t0 = time.time()
        ekf_ok_at = wait_ekf(gcs, spec.ekf_wait_s)
        figures: dict[str, Any] = {"ekf_position_after_s": None if ekf_ok_at is None else ekf_ok_at - t0}
        if ekf_ok_at is None:  # say why, in the result: what the daemon and the autopilot last said
            figures["verdict"] = "ekf_never_ready"
            figures["daemon_log_tail"] = log_tail(out / "daemon.log")
            figures["sitl_log_tail"] = log_tail(sitl_dir / "out.log")
            if fault is not None:
                figures.update(fault.figures(out / "daemon"))
            return _finish(out, gcs, spec, figures, None)
        armed_at = arm(gcs)
        gcs.send_cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ROVER_AUTO)
        auto_t = time.time()
        figures["armed_after_s"] = armed_at - t0
        gnss_off_t = restart_t = None
        last_seq = n_items - 1
        done = False
        while time.time() - auto_t < spec.timeout_s and not done:
            if spec.restart_after_s is not None and restart_t is None and time.time() - auto_t >= spec.restart_after_s:
                stop_group(daemon, signal.SIGTERM)  # as a service manager stops it, then the same command again
                daemon = subprocess.Popen(daemon_cmd, stdout=open(out / "daemon_restarted.log", "w"),
                                          stderr=subprocess.STDOUT, start_new_session=True)
                restart_t = time.time()
            for msg in gcs.pump(0.5):
                kind = msg.get_type()
                if kind == "MISSION_ITEM_REACHED" and msg.seq >= last_seq:
                    done = True
            if fault is not None:
                fault.step(time.time() - auto_t)
            if spec.setup == "handover" and gnss_off_t is None and time.time() - auto_t >= spec.gnss_off_after_s:
                gcs.set_param("SIM_GPS1_ENABLE", 0)
                gnss_off_t = time.time()
            if runaway(gcs, spec):
                figures["verdict"] = "runaway_stopped"
                break
        gcs.pump(2.0)
        figures["mission_completed"] = done
        figures["mission_s"] = time.time() - auto_t
        figures["gnss_off_after_auto_s"] = None if gnss_off_t is None else gnss_off_t - auto_t
        figures["daemon_restarted_after_auto_s"] = None if restart_t is None else restart_t - auto_t
        if fault is not None:
            figures.update(fault.figures(out / "daemon"))
        return _finish(out, gcs, spec, figures, auto_t)
    finally:
        stop_group(daemon, signal.SIGINT)
        stop_group(sitl, signal.SIGTERM)
        if fault is not None:
            fault.close()


def log_tail(path: Path, lines: int = 25) -> list[str]:
    """The last `lines` lines of a log file ([] when it is missing): for a result that explains a failed start."""
    try:
        return path.read_text(errors="replace").splitlines()[-lines:]
    except OSError:
        return []


def stop_group(proc: subprocess.Popen | None, first: int, wait_s: float = 15.0) -> None:
    """End a process started with start_new_session=True and everything in its group: `first` (SIGINT for the
    daemon, which then closes its logs; SIGTERM for an autopilot), SIGKILL after wait_s."""
    if proc is not None and proc.poll() is None:
        os.killpg(proc.pid, first)
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


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


def runaway(gcs: Gcs, spec: Any, truth_kind: str = "SIMSTATE", truth_lon: str = "lng",
            hold: tuple[float, ...] = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ROVER_HOLD)) -> bool:
    """Truth (the latest `truth_kind`, lat and `truth_lon` in degE7) more than 3 spec.side_m from spec.home:
    stop early (MAV_CMD_DO_SET_MODE with `hold`, the autopilot's HOLD), the run has failed anyway."""
    for _, msg in reversed(gcs.log[-50:]):
        if msg.get_type() == truth_kind:
            e, n = metres_between(spec.home[0], spec.home[1], msg.lat * 1e-7, getattr(msg, truth_lon) * 1e-7)
            if math.hypot(e, n) > 3 * spec.side_m:
                gcs.send_cmd(M.MAV_CMD_DO_SET_MODE, *hold)
                return True
            return False
    return False


def _finish(out: Path, gcs: Gcs, spec: MissionSpec, figures: dict[str, Any], auto_t: float | None) -> dict[str, Any]:
    figures.update(score(gcs.log, spec, auto_t, out))
    figures.update(sent_score(out / "daemon", spec, auto_t, out))
    figures.update(shadow_score(out / "daemon", spec))
    gcs.write_tlog(out / "gcs.tlog")
    figures["spec"] = asdict(spec)
    figures["statustext"] = [t for _, _, t in gcs.texts if ("taco" in t.lower() or "GPS" in t or "EKF" in t)
                             and "fix rejected" not in t and "fix accepted" not in t][-40:]
    (out / "result.json").write_text(json.dumps(figures, indent=2, default=float))
    return figures


def score(log: list[tuple[float, Any]], spec: Any, auto_t: float | None, out: Path | None = None, *,
          truth_kind: str = "SIMSTATE", truth_lon: str = "lng", ours_kind: str | None = None,
          cruise_mps: float | None = None) -> dict[str, Any]:
    """Figures from the GCS log: truth (`truth_kind`, lat and `truth_lon` in degE7: ArduPilot's SIMSTATE, PX4's
    HIL_STATE_QUATERNION) at 10 Hz, stamped by arrival wall time, the EKF (GLOBAL_POSITION_INT) and our
    instance's report (`ours_kind`; default GPS_RAW_INT in solo, GPS2_RAW in handover) each paired with the
    latest truth before it; errors are horizontal metres about spec.home. The speed limit is 1.5 x cruise_mps
    (default spec.wp_speed), m/s. With `out`, truth.csv, ekf_error.csv and ours_error.csv go there (from AUTO
    on)."""
    lat0, lon0 = spec.home[0], spec.home[1]
    truth = [(t, *metres_between(lat0, lon0, m.lat * 1e-7, getattr(m, truth_lon) * 1e-7)) for t, m in log
             if m.get_type() == truth_kind]
    if len(truth) < 10:
        return {"error": f"no {truth_kind}"}
    T = np.array(truth)
    if ours_kind is None:
        ours_kind = "GPS_RAW_INT" if spec.setup == "solo" else "GPS2_RAW"
    if cruise_mps is None:
        cruise_mps = spec.wp_speed

    def paired(kind: str, lat: str, lon: str, scale: float) -> np.ndarray:
        rows = []
        for t, m in log:
            if m.get_type() != kind or (auto_t is not None and t < auto_t):
                continue
            if kind != "GLOBAL_POSITION_INT" and m.fix_type < 3 or m.lat == 0 and m.lon == 0:
                continue  # no fix, or an EKF without an origin
            i = int(np.searchsorted(T[:, 0], t)) - 1
            if i < 0:
                continue
            e, n = metres_between(lat0, lon0, getattr(m, lat) * scale, getattr(m, lon) * scale)
            acc = getattr(m, "h_acc", 0) * 1e-3 if kind != "GLOBAL_POSITION_INT" else 0.0
            rows.append((t, math.hypot(e - T[i, 1], n - T[i, 2]), acc))
        return np.array(rows).reshape(-1, 3)

    ekf = paired("GLOBAL_POSITION_INT", "lat", "lon", 1e-7)
    ours = paired(ours_kind, "lat", "lon", 1e-7)
    bounded = _ekf_bounded_share(log, T, ekf, ours_kind, auto_t)
    live = T[T[:, 0] >= auto_t] if auto_t is not None else T
    dt = np.diff(live[:, 0])
    speed = np.hypot(np.diff(live[:, 1]), np.diff(live[:, 2])) / np.maximum(dt, 1e-3)
    speed = speed[dt > 0.05]
    # a 1 s median keeps the truth's arrival jitter out of the speed
    k = 10
    smooth = np.array([np.median(speed[i:i + k]) for i in range(max(len(speed) - k, 0))]) if len(speed) > k else speed
    res: dict[str, Any] = {
        "ekf_rms_m": float(np.sqrt(np.mean(ekf[:, 1] ** 2))) if len(ekf) else None,
        "ekf_max_m": float(ekf[:, 1].max()) if len(ekf) else None,
        "true_speed_max_mps": float(smooth.max()) if len(smooth) else None,
        "true_speed_limit_mps": 1.5 * cruise_mps,
        "ours_reports": int(len(ours)),
        "ours_rms_m": float(np.sqrt(np.mean(ours[:, 1] ** 2))) if len(ours) else None,
        "ours_max_m": float(ours[:, 1].max()) if len(ours) else None,
        # error over reported 1-sigma (h_acc); > 3 means we claimed far more than we had
        "ours_error_over_hacc_max": float((ours[:, 1] / np.maximum(ours[:, 2], 0.1)).max()) if len(ours) else None,
        "ours_hacc_median_m": float(np.median(ours[:, 2])) if len(ours) else None,
        "ekf_within_bound_moving_share": bounded,
    }
    if out is not None:
        np.savetxt(out / "truth.csv", T, fmt="%.3f", delimiter=",", header="wall_s,east_m,north_m")
        np.savetxt(out / "ekf_error.csv", ekf[:, :2], fmt="%.3f", delimiter=",", header="wall_s,error_m")
        np.savetxt(out / "ours_error.csv", ours, fmt="%.3f", delimiter=",", header="wall_s,error_m,h_acc_m")
    return res


def _ekf_bounded_share(log: list[tuple[float, Any]], T: np.ndarray, ekf: np.ndarray, ours_kind: str,
                       auto_t: float | None, moving_mps: float = 0.5) -> float | None:
    """Share of the EKF's samples taken while the rover moves (truth faster than moving_mps) whose error is within
    max(3 m, 2 x the 1-sigma we last reported): `ours_kind`'s h_acc, whatever its fix type (a degraded report's
    accuracy counts: it told the autopilot how little to trust it). Issue 37's bound for a camera that cannot read
    the ground. None without such samples."""
    acc = [(t, m.h_acc * 1e-3) for t, m in log if m.get_type() == ours_kind and (auto_t is None or t >= auto_t)]
    if not acc or len(ekf) == 0 or len(T) < 3:
        return None
    A = np.array(acc)
    dt = np.maximum(np.diff(T[:, 0]), 1e-3)
    v = np.r_[0.0, np.hypot(np.diff(T[:, 1]), np.diff(T[:, 2])) / dt]
    v = np.convolve(v, np.ones(10) / 10.0, mode="same")  # 1 s mean: the truth's arrival jitter out
    ok = []
    for t, err, _ in ekf:
        i, j = int(np.searchsorted(T[:, 0], t)) - 1, int(np.searchsorted(A[:, 0], t)) - 1
        if i < 0 or j < 0 or v[i] < moving_mps:
            continue
        ok.append(err <= max(3.0, 2.0 * A[j, 1]))
    return float(np.mean(ok)) if ok else None


def sent_score(daemon_dir: Path, spec: Any, auto_t: float | None, out: Path | None = None, *,
               truth_kind: str = "SIMSTATE", truth_lon: str = "lng") -> dict[str, Any]:
    """Our reports scored where they were made: every GPS_INPUT / HIL_GPS (fix type >= 3) in the daemon's own
    tlog (daemon_dir/*/mav.tlog, both directions stamped on the daemon's wall clock) against the truth the daemon
    heard (`truth_kind`, interpolated to the send time), with the 1-sigma it claimed (GPS_INPUT horiz_accuracy m,
    HIL_GPS eph cm). The ground station's echo (`score`) adds the autopilot's store-and-forward delay to the error,
    up to a metre at 3 m/s; this does not. Figures: ours_sent_* (error m, error over 1-sigma max / median, share
    within 2 and 3 sigma); with `out`, ours_sent_error.csv."""
    tlogs = sorted(Path(daemon_dir).glob("*/mav.tlog"))
    if not tlogs:
        return {"ours_sent_error": f"no daemon tlog under {daemon_dir}"}
    lat0, lon0 = spec.home[0], spec.home[1]
    truth: list[tuple[float, float, float]] = []
    sent: list[tuple[float, float, float, float]] = []
    gaps: list[float] = []  # s between consecutive position messages of one session
    for path in tlogs:
        mlog = mavutil.mavlink_connection(str(path))
        last_sent = None
        while (m := mlog.recv_match(type=[truth_kind, "GPS_INPUT", "HIL_GPS"])) is not None:
            kind, t = m.get_type(), float(m._timestamp)
            if kind != truth_kind:
                if last_sent is not None and (auto_t is None or t >= auto_t):
                    gaps.append(t - last_sent)
                last_sent = t
            if kind == truth_kind:
                if m.lat or getattr(m, truth_lon):
                    truth.append((t, *metres_between(lat0, lon0, m.lat * 1e-7, getattr(m, truth_lon) * 1e-7)))
            elif m.fix_type >= 3 and (auto_t is None or t >= auto_t):
                acc = float(m.horiz_accuracy) if kind == "GPS_INPUT" else m.eph * 1e-2
                sent.append((t, *metres_between(lat0, lon0, m.lat * 1e-7, m.lon * 1e-7), acc))
    if len(truth) < 10 or not sent:
        return {"ours_sent_error": f"{len(truth)} {truth_kind}, {len(sent)} reports in the daemon tlog"}
    T, S = np.array(sorted(truth)), np.array(sent)
    S = S[(S[:, 0] >= T[0, 0]) & (S[:, 0] <= T[-1, 0])]
    te, tn = np.interp(S[:, 0], T[:, 0], T[:, 1]), np.interp(S[:, 0], T[:, 0], T[:, 2])
    err = np.hypot(S[:, 1] - te, S[:, 2] - tn)
    ratio = err / np.maximum(S[:, 3], 0.1)
    if out is not None:
        np.savetxt(out / "ours_sent_error.csv", np.column_stack([S[:, 0], err, S[:, 3]]), fmt="%.3f",
                   delimiter=",", header="wall_s,error_m,h_acc_m")
    return {"ours_sent_reports": int(len(err)), "ours_sent_rms_m": float(np.sqrt(np.mean(err**2))),
            "ours_sent_interval_p50_ms": float(np.percentile(gaps, 50) * 1e3) if gaps else None,
            "ours_sent_interval_p99_ms": float(np.percentile(gaps, 99) * 1e3) if gaps else None,
            "ours_sent_error_over_hacc_max": float(ratio.max()),
            "ours_sent_error_over_hacc_median": float(np.median(ratio)),
            # a calibrated 2-D Gaussian puts 86.5 % within 2 sigma (Rayleigh) and 98.9 % within 3
            "ours_sent_within_2_hacc": float(np.mean(ratio <= 2.0)),
            "ours_sent_within_3_hacc": float(np.mean(ratio <= 3.0))}


def shadow_score(daemon_dir: Path, spec: Any, truth_kind: str = "SIMSTATE", truth_lon: str = "lng") -> dict[str, Any]:
    """`--shadow` figures: the `shadow` events' gnss_err_m (the GNSS-free twin's distance to the receiver) beside
    the twin's true error (its lat, lon against the truth in the daemon's tlog at the event's wall time); none
    without shadow events."""
    events = [e for e in read_events(daemon_dir) if e.get("event") == "shadow"]
    if not events:
        return {}
    lat0, lon0 = spec.home[0], spec.home[1]
    truth = []
    for path in sorted(Path(daemon_dir).glob("*/mav.tlog")):
        mlog = mavutil.mavlink_connection(str(path))
        while (m := mlog.recv_match(type=[truth_kind])) is not None:
            if m.lat or getattr(m, truth_lon):
                east_north = metres_between(lat0, lon0, m.lat * 1e-7, getattr(m, truth_lon) * 1e-7)
                truth.append((float(m._timestamp), *east_north))
    T = np.array(sorted(truth))
    tw = np.array([e["t_wall"] for e in events])
    twin = np.array([metres_between(lat0, lon0, e["lat"], e["lon"]) for e in events])
    true_err = np.hypot(twin[:, 0] - np.interp(tw, T[:, 0], T[:, 1]), twin[:, 1] - np.interp(tw, T[:, 0], T[:, 2]))
    told = np.array([e["gnss_err_m"] for e in events])
    return {"shadow_reports": len(events), "shadow_gnss_err_median_m": float(np.median(told)),
            "shadow_true_err_median_m": float(np.median(true_err)),
            "shadow_true_err_p95_m": float(np.percentile(true_err, 95))}


def accuracy_failures(res: dict[str, Any], within_2: float | None = 0.8, within_3: float = 0.95,
                      max_ratio: float = 5.0) -> list[str]:
    """What breaks "the reported accuracy covers the error" in `sent_score`'s figures (empty when it holds): at
    least `within_2` of the reports within 2 sigma (None: not asked) and `within_3` within 3 (a calibrated
    isotropic Gaussian: 86.5 and 98.9 %), none beyond `max_ratio` (never again 1.2 m reported at 53 m)."""
    if "ours_sent_reports" not in res:
        return [str(res.get("ours_sent_error", "no at-send figures"))]
    bounds = [("ours_sent_within_3_hacc", within_3, 1), ("ours_sent_error_over_hacc_max", max_ratio, -1)]
    if within_2 is not None:
        bounds.insert(0, ("ours_sent_within_2_hacc", within_2, 1))
    return [f"{key} {res[key]:.3f} (bound {bound})" for key, bound, sign in bounds if sign * (res[key] - bound) < 0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ardurover", default=os.environ.get("ARDUROVER"), help="SITL binary (default $ARDUROVER)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--setup", choices=("solo", "handover"), default="solo")
    ap.add_argument("--estimator", choices=("paper", "taco+"), default="taco+")
    ap.add_argument("--laps", type=int, default=2)
    ap.add_argument("--side", type=float, default=60.0)
    ap.add_argument("--wp-speed", type=float, default=3.0)
    ap.add_argument("--gnss-off-after", type=float, default=30.0)
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--profile", help="daemon profile (default ardupilot_rover; handover: ardupilot_rover_gps2)")
    ap.add_argument("--daemon-origin", action="store_true", help="start the daemon with --origin (SITL's home)")
    ap.add_argument("--daemon-arg", action="append", default=[], help="one more `taco-mav run` option (repeat: "
                    "--daemon-arg=--record --daemon-arg=--shadow)")
    ap.add_argument("--realism", choices=("flat", "3d"), default="flat",
                    help="the synthetic world (`taco-mav world --realism`): flat (default) or 3d")
    ap.add_argument("--restart-after", type=float, help="SIGTERM the daemon this many seconds after AUTO and start "
                                                          "it again with the same command")
    ap.add_argument("--fault", choices=FAULT_KINDS, help="a fault on cue (tools/sitl_faults.py; glitch and spoof "
                                                         "need --setup handover)")
    ap.add_argument("--fault-after", type=float, default=60.0, help="seconds after AUTO the fault starts")
    ap.add_argument("--world-seed", type=int, default=7, help="the world's seed (default 7)")
    ap.add_argument("--through", action="store_true", help="3d: drive the square through the buildings and trees "
                    "(no --keep-clear)")
    ap.add_argument("--map-seed", type=int, help="give the daemon another world's map (this seed) over the same "
                    "ground: a camera that cannot read the map it has")
    a = ap.parse_args()
    if not a.ardurover or not Path(a.ardurover).exists():
        print("sitl_mission: error: --ardurover (or $ARDUROVER) must name the SITL binary", file=sys.stderr)
        return 2
    spec = MissionSpec(side_m=a.side, laps=a.laps, wp_speed=a.wp_speed, setup=a.setup,
                       gnss_off_after_s=a.gnss_off_after, estimator=a.estimator, timeout_s=a.timeout,
                       daemon_origin=a.daemon_origin, restart_after_s=a.restart_after,
                       daemon_args=tuple(a.daemon_arg), fault=a.fault, fault_after_s=a.fault_after,
                       realism=a.realism, world_seed=a.world_seed, map_seed=a.map_seed, keep_clear=not a.through,
                       profile=a.profile or ("ardupilot_rover_gps2" if a.setup == "handover" else "ardupilot_rover"))
    res = run_mission(Path(a.ardurover), Path(a.out), spec)
    print(json.dumps({k: v for k, v in res.items() if k not in ("spec", "statustext")}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
