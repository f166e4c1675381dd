#!/usr/bin/env python3
"""Closed loop on PX4: SIH (PX4's built-in simulator, no Gazebo) Ackermann rover driven by taco-mav.

The sibling of tools/sitl_mission.py (ArduPilot Rover SITL), sharing its ground station, mission upload and
scoring. Starts PX4 SITL (built by ../shared/tools/build_px4_sitl.sh) as instance I >= 3 with a private command
folder and a fresh rootfs under OUT/px4, the daemon (`taco-mav run`, a subprocess exactly as a user starts it) on
PX4's onboard MAVLink link with a camera rendered from a synthetic world centred on SIH's home (Zurich), uploads a
square mission, arms, drives in AUTO.MISSION and scores:
- EKF2's position (GLOBAL_POSITION_INT) against SIH's truth (HIL_STATE_QUATERNION), metres;
- the rover's true speed (differentiated truth, 1 s median) against RO_SPEED_LIM (the Mission-mode cruise), m/s;
- our own output (the GPS instance that is ours: GPS_RAW_INT in solo, GPS2_RAW in handover) against the truth,
  with the horizontal accuracy we reported beside it;
- whether PX4 failed safe or disarmed (STATUSTEXT, HEARTBEAT), with its last 40 STATUSTEXTs.

Set-ups:
- `gnss`: PX4's own simulated receiver only, no daemon (the baseline; airframe 10045);
- `solo`: airframe 10046 (SENS_EN_GPSSIM 0, MAV_USEHILGPS 1): GNSS only from the daemon's HIL_GPS; the ground
  station sets EKF2's origin at home (spec.gcs_sets_origin);
- `handover`: airframe 10045 with MAV_USEHILGPS 1: PX4's simulated receiver steers the rover, the daemon's HIL_GPS
  is a second receiver; SIM_GPS_USED 0 part-way through the mission switches the simulated one off.

    python tools/px4_mission.py --px4 $PX4_SITL --out /tmp/px4_1 [--setup solo|handover|gnss] [--estimator paper]

Writes OUT/result.json (the figures), OUT/truth.csv, ekf_error.csv, ours_error.csv (as sitl_mission), gcs.tlog
(all the ground station heard), the daemon's tlog and events in OUT/daemon/<UTC start time>/, OUT/daemon.log, and
OUT/px4/ (rootfs with PX4's log and parameters, out.log: its console). Nothing here is product code:
tests/test_px4.py runs it when PX4_SITL is set.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sitl_mission import Gcs, M, arm, build_world, mavutil, score, sent_score, set_ekf_origin  # noqa: E402
from sitl_mission import log_tail, stop_group, wait_ekf  # noqa: E402
from sitl_mission import runaway as _runaway  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
HOME = (47.397743, 8.545594, 488.9, 0.0)  # SIH's home (lat, lon, alt m AMSL, heading deg)
# PX4 custom modes (px4_custom_mode.h): main mode AUTO 4; its sub modes LOITER 3 (a rover holds), MISSION 4.
# MAV_CMD_DO_SET_MODE param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, param2 = main, param3 = sub.
PX4_MAIN_AUTO, PX4_AUTO_LOITER, PX4_AUTO_MISSION = 4, 3, 4
MODE_MISSION = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MAIN_AUTO, PX4_AUTO_MISSION)
MODE_HOLD = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MAIN_AUTO, PX4_AUTO_LOITER)
MISSION_STATE_ACTIVE, MISSION_STATE_COMPLETE = 3, 5
MODELS = {"solo": "sihsim_rover_ackermann_extgps", "handover": "sihsim_rover_ackermann",
          "gnss": "sihsim_rover_ackermann"}
TRUTH = "HIL_STATE_QUATERNION"  # SIH's ground truth; lat/lon degE7, time_usec 0 (stamped by arrival)
# STATUSTEXT words that mean PX4 failed safe, gave up a mode or disarmed
FAILSAFE_WORDS = ("failsafe", "disarm", "navigation error", "no valid position", "position estimate",
                  "return", "land", "hold")


@dataclass
class Px4MissionSpec:
    """What to drive. side_m: square side, metres (first leg north from home); laps; cruise_speed: RO_SPEED_LIM,
    m/s (Mission-mode cruise); setup: solo | handover | gnss; gnss_off_after_s: handover only, wall seconds after
    AUTO.MISSION when SIM_GPS_USED=0; timeout_s: wall seconds allowed for the mission after AUTO.MISSION;
    ekf_wait_s: wall seconds allowed for EKF2's first global position; gcs_sets_origin: the ground station sends
    SET_GPS_GLOBAL_ORIGIN (home) until PX4 reports it (None: solo only, where no receiver gives EKF2 one);
    params_file: a QGroundControl parameter file set at boot, as a user loads it ("auto": the one shipped beside
    the profiles for the setup, vehicle_profiles/px4_rover_<setup>.params, where there is one; "": none);
    extra_params: PX4 parameters set at boot after it (PX4_PARAM_<NAME>); daemon_args: appended to
    `taco-mav run`."""

    side_m: float = 60.0
    laps: int = 2
    cruise_speed: float = 3.0
    setup: str = "solo"
    gnss_off_after_s: float = 30.0
    estimator: str = "taco+"
    profile: str = "px4_rover"
    world_seed: int = 7
    timeout_s: float = 300.0
    ekf_wait_s: float = 150.0
    home: tuple[float, float, float, float] = HOME
    extra_params: dict[str, float] = field(default_factory=dict)
    gcs_sets_origin: bool | None = None
    daemon_args: list[str] = field(default_factory=list)
    params_file: str = "auto"
    restart_after_s: float | None = None  # SIGTERM the daemon this long after AUTO.MISSION and start it again
    realism: str = "flat"  # the world the camera sees (sitl_mission.build_world): flat or 3d
    keep_clear: bool = True  # a 3-D world keeps its buildings and trees off the square (tools/sitl_mission.build_world)

    def sets_origin(self) -> bool:
        return self.setup == "solo" if self.gcs_sets_origin is None else self.gcs_sets_origin


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _lock_free(inst: int) -> bool:
    """/tmp/px4_lock-I absent, or present and not held (PX4 holds it with lockf while it runs)."""
    path = f"/tmp/px4_lock-{inst}"
    try:
        fd = os.open(path, os.O_RDWR)
    except FileNotFoundError:
        return True
    except OSError:
        return False  # another user's lock file
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.lockf(fd, fcntl.LOCK_UN)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def free_instance(first: int = 3) -> int:
    """A PX4 instance I >= first whose lock is free and whose UDP ports are: GCS 18570+I, onboard 14580+I and
    its remote 14540+I (the daemon binds it), and the other links rcS starts (14280+I, 13030+I, 19450+I)."""
    for inst in range(first, first + 40):
        if _lock_free(inst) and all(_udp_free(p + inst) for p in (18570, 14580, 14540, 14280, 13030, 19450)):
            return inst
    raise RuntimeError("no free PX4 instance")


def prepare_px4(px4: Path, folder: Path) -> tuple[Path, Path]:
    """A private command folder and a fresh rootfs under `folder`; returns (the px4 link to run, rootfs).

    The shared build's bin/px4-* command links are plain files, so rcS's `px4-param ...` fails: the private
    folder holds px4 -> the binary and px4-<name> -> px4 for each of them (px4-alias.sh copied). The rootfs
    holds etc -> the build's ROMFS."""
    real = px4.resolve()
    shutil.rmtree(folder, ignore_errors=True)
    bindir, rootfs = folder / "bin", folder / "rootfs"
    bindir.mkdir(parents=True)
    rootfs.mkdir()
    (bindir / "px4").symlink_to(real)
    for f in sorted(real.parent.glob("px4-*")):
        if f.name == "px4-alias.sh":
            shutil.copy(f, bindir / f.name)
        else:
            (bindir / f.name).symlink_to("px4")
    (rootfs / "etc").symlink_to(real.parents[1] / "etc")
    return bindir / "px4", rootfs


def _param_text(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def read_params_file(path: Path) -> dict[str, float]:
    """NAME -> value from a QGroundControl parameter file (tab-separated vehicle, component, name, value, type;
    # comments)."""
    out: dict[str, float] = {}
    for line in path.read_text().splitlines():
        cols = line.split("\t")
        if line.startswith("#") or len(cols) < 4:
            continue
        out[cols[2].strip()] = float(cols[3])
    return out


def params_file(spec: Px4MissionSpec) -> Path | None:
    """The parameter file spec.params_file names (see Px4MissionSpec), or None."""
    if spec.params_file == "auto":
        shipped = ROOT / "vehicle_profiles" / f"px4_rover_{spec.setup}.params"
        return shipped if spec.setup != "gnss" and shipped.is_file() else None
    return Path(spec.params_file) if spec.params_file else None


def px4_params(spec: Px4MissionSpec) -> dict[str, float]:
    """PX4 parameters of the set-up, set at boot through PX4_PARAM_<NAME> (the airframe's model does the rest):
    the cruise, the parameter file, MAV_USEHILGPS 1 in handover (airframe 10045 leaves it 0), extra_params."""
    if spec.setup not in ("solo", "handover", "gnss"):
        raise ValueError(f"setup {spec.setup!r}: solo, handover or gnss")
    p: dict[str, float] = {"RO_SPEED_LIM": spec.cruise_speed}
    f = params_file(spec)
    if f is not None:
        p.update(read_params_file(f))
    if spec.setup == "handover":
        p["MAV_USEHILGPS"] = 1
    p.update(spec.extra_params)
    return p


def start_px4(px4: Path, folder: Path, inst: int, spec: Px4MissionSpec) -> subprocess.Popen:
    """PX4 SITL (SIH) instance `inst` in its own process group; console to folder/out.log."""
    exe, rootfs = prepare_px4(px4, folder)
    env = dict(os.environ, PX4_SIMULATOR="sihsim", PX4_SIM_MODEL=MODELS[spec.setup])
    env.update({f"PX4_PARAM_{k}": _param_text(v) for k, v in px4_params(spec).items()})
    return subprocess.Popen([str(exe), "-d", "-i", str(inst), "-w", str(rootfs)], cwd=rootfs, env=env,
                            stdin=subprocess.DEVNULL, stdout=open(folder / "out.log", "w"),
                            stderr=subprocess.STDOUT, start_new_session=True)


class Px4Gcs(Gcs):
    """The harness's ground station on PX4's GCS link (UDP 18570+I; PX4 answers whoever sends to it, so it
    sends a HEARTBEAT every second)."""

    heartbeat_s = 1.0

    def __init__(self, inst: int, limit_s: float = 60.0) -> None:
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{18570 + inst}", source_system=250, source_component=190)
        deadline = time.time() + limit_s
        while True:
            try:
                m.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            except OSError:
                pass  # PX4 not listening yet
            hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=1)
            if hb is not None and hb.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1:
                break
            if time.time() > deadline:
                raise RuntimeError(f"no PX4 heartbeat on UDP {18570 + inst}")
        m.target_system = hb.get_srcSystem()
        self._attach(m)


def px4_mode(custom_mode: int) -> tuple[int, int]:
    """(main mode, sub mode) of a PX4 HEARTBEAT custom_mode."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def set_mode(gcs: Gcs, mode: tuple[float, float, float], limit_s: float = 10.0) -> bool:
    """MAV_CMD_DO_SET_MODE `mode` (MODE_MISSION, MODE_HOLD) once a second until PX4's HEARTBEAT shows its main
    and sub mode; False after limit_s (PX4 refuses a mode it cannot fly, e.g. Mission without a position)."""
    want = (int(mode[1]), int(mode[2]))
    end = time.time() + limit_s
    while time.time() < end:
        gcs.send_cmd(M.MAV_CMD_DO_SET_MODE, *mode)
        for msg in gcs.pump(1.0):
            if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == gcs.target[0] and \
                    msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 and px4_mode(msg.custom_mode) == want:
                return True
    return False


def run_px4_mission(px4: Path, out: Path, spec: Px4MissionSpec, world: Path | None = None) -> dict[str, Any]:
    """Drive `spec` on PX4 SITL (SIH) with taco-mav in the loop (not in setup gnss); returns the figures (also
    written to OUT/result.json)."""
    px4_params(spec)  # refuses an unknown setup before anything starts
    out.mkdir(parents=True, exist_ok=True)
    if spec.setup != "gnss":
        world = world or build_world(out, spec)
    inst = free_instance()
    proc = start_px4(px4, out / "px4", inst, spec)
    daemon = None
    figures: dict[str, Any] = {"instance": inst, "px4_params": px4_params(spec)}
    try:
        gcs = Px4Gcs(inst)
        t0 = time.time()
        if spec.setup != "gnss":
            daemon_cmd = [sys.executable, "-m", "taco_mav.cli", "run", "--profile", spec.profile, "--connect",
                          f"udpin:127.0.0.1:{14540 + inst}", "--camera", f"world:{world}", "--log-dir",
                          str(out / "daemon"), "--estimator", spec.estimator, *spec.daemon_args]
            shutil.rmtree(out / "daemon", ignore_errors=True)
            daemon = subprocess.Popen(daemon_cmd, stdout=open(out / "daemon.log", "w"), stderr=subprocess.STDOUT,
                                      start_new_session=True)
        for mid, hz in ((M.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 10), (M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 10),
                        (M.MAVLINK_MSG_ID_GPS_RAW_INT, 5), (M.MAVLINK_MSG_ID_GPS2_RAW, 5),
                        (M.MAVLINK_MSG_ID_MISSION_CURRENT, 2), (M.MAVLINK_MSG_ID_ESTIMATOR_STATUS, 2),
                        # PX4 streams these at 50 Hz to a ground station; the harness needs none of them
                        (M.MAVLINK_MSG_ID_ATTITUDE, 2), (M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 2),
                        (M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 2)):
            gcs.interval(mid, hz)
        if spec.sets_origin():
            figures["origin_taken_after_s"] = set_ekf_origin(gcs, spec.home)
        n_items = gcs.upload_square(spec.home, spec.side_m, spec.laps, home_item=False,
                                    frame=M.MAV_FRAME_GLOBAL_INT, alt=spec.home[2])
        # ESTIMATOR_STATUS: PX4 sets CONST_POS_MODE at rest (EKF2's vehicle_at_rest), so that bit is no refusal
        ekf_ok_at = wait_ekf(gcs, spec.ekf_wait_s, status_kind="ESTIMATOR_STATUS", need_global=True, refuse=0)
        figures["ekf_position_after_s"] = None if ekf_ok_at is None else ekf_ok_at - t0
        if ekf_ok_at is None:
            figures["verdict"] = "ekf_never_ready"  # say why: what the daemon and PX4 last said
            figures["daemon_log_tail"] = log_tail(out / "daemon.log")
            figures["px4_log_tail"] = log_tail(out / "px4" / "out.log")
            return _finish(out, gcs, spec, figures, None, daemon)
        try:
            armed_at = arm(gcs)
        except RuntimeError as e:
            figures["verdict"] = "arming_refused"
            figures["arming_error"] = str(e)
            return _finish(out, gcs, spec, figures, None, daemon)
        figures["armed_after_s"] = armed_at - t0
        auto_t = time.time()
        if not set_mode(gcs, MODE_MISSION):
            figures["verdict"] = "mission_mode_refused"
            return _finish(out, gcs, spec, figures, auto_t, daemon)
        def restart() -> None:  # as a service manager restarts it: SIGTERM, then the same command again
            nonlocal daemon
            stop_group(daemon, signal.SIGTERM)
            daemon = subprocess.Popen(daemon_cmd, stdout=open(out / "daemon_restarted.log", "w"),
                                      stderr=subprocess.STDOUT, start_new_session=True)

        figures.update(_drive(gcs, spec, n_items, auto_t, restart if daemon is not None else None))
        return _finish(out, gcs, spec, figures, auto_t, daemon)
    finally:
        stop_group(daemon, signal.SIGINT)
        stop_group(proc, signal.SIGTERM)


def _drive(gcs: Px4Gcs, spec: Px4MissionSpec, n_items: int, auto_t: float,
           restart: Callable[[], None] | None = None) -> dict[str, Any]:
    """Pump until the last item is reached (MISSION_ITEM_REACHED) or MISSION_CURRENT says complete after it was
    active, the timeout, a runaway, or PX4 disarming; hand-over: SIM_GPS_USED 0 after gnss_off_after_s;
    `restart` (the daemon's) called once spec.restart_after_s after AUTO.MISSION."""
    res: dict[str, Any] = {}
    gnss_off_t = restart_t = None
    last_seq = n_items - 1
    done = active = False
    reached = -1
    disarmed_t = None
    while time.time() - auto_t < spec.timeout_s and not done:
        for msg in gcs.pump(0.5):
            kind = msg.get_type()
            if kind == "MISSION_ITEM_REACHED":
                reached = max(reached, msg.seq)
                done = done or msg.seq >= last_seq
            elif kind == "MISSION_CURRENT":
                active = active or msg.mission_state == MISSION_STATE_ACTIVE
                done = done or (active and msg.mission_state == MISSION_STATE_COMPLETE)
            elif kind == "HEARTBEAT" and msg.get_srcSystem() == gcs.target[0] and \
                    msg.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1 and \
                    not msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and disarmed_t is None:
                disarmed_t = time.time()
        if spec.setup == "handover" and gnss_off_t is None and time.time() - auto_t >= spec.gnss_off_after_s:
            gcs.set_param("SIM_GPS_USED", 0, M.MAV_PARAM_TYPE_INT32)
            gnss_off_t = time.time()
        if restart is not None and spec.restart_after_s is not None and restart_t is None \
                and time.time() - auto_t >= spec.restart_after_s:
            restart()
            restart_t = time.time()
        if _runaway(gcs, spec, truth_kind=TRUTH, truth_lon="lon", hold=MODE_HOLD):
            res["verdict"] = "runaway_stopped"
            break
        if disarmed_t is not None and not done:
            res["verdict"] = "disarmed"
            break
    gcs.pump(2.0)
    res["mission_completed"] = done
    res["mission_items"] = n_items
    res["last_item_reached"] = reached
    res["mission_s"] = time.time() - auto_t
    res["gnss_off_after_auto_s"] = None if gnss_off_t is None else gnss_off_t - auto_t
    res["disarmed_after_auto_s"] = None if disarmed_t is None else disarmed_t - auto_t
    res["daemon_restarted_after_auto_s"] = None if restart_t is None else restart_t - auto_t
    return res


def _modes(gcs: Gcs, t_ref: float) -> list[dict[str, Any]]:
    """Each change of PX4's (armed, main mode, sub mode) in the autopilot's HEARTBEATs, wall s after t_ref."""
    seen: list[dict[str, Any]] = []
    last = None
    for t, msg in gcs.log:
        if msg.get_type() != "HEARTBEAT" or msg.get_srcSystem() != gcs.target[0] or \
                msg.get_srcComponent() != M.MAV_COMP_ID_AUTOPILOT1:
            continue
        main, sub = px4_mode(msg.custom_mode)
        now = (bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED), main, sub)
        if now != last:
            seen.append({"t_s": round(t - t_ref, 2), "armed": now[0], "main": main, "sub": sub})
            last = now
    return seen


def statustexts(gcs: Gcs) -> list[tuple[float, int, int, str]]:
    """(wall time, sender's component id, severity, text) of each STATUSTEXT in the GCS log, PX4's chunks
    joined: a text longer than 50 characters comes as several messages with the same non-zero id and chunk_seq
    0, 1, ... The daemon's texts (component 191) reach the ground station through PX4 too."""
    out: list[tuple[float, int, int, str]] = []
    last = None
    for t, msg in gcs.log:
        if msg.get_type() != "STATUSTEXT":
            continue
        key = (msg.get_srcComponent(), getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0))
        if key[1] and last is not None and key[:2] == last[:2] and key[2] == last[2] + 1 and out:
            out[-1] = out[-1][:3] + (out[-1][3] + msg.text,)
        else:
            out.append((t, key[0], msg.severity, msg.text))
        last = key
    return [(t, comp, sev, txt.strip()) for t, comp, sev, txt in out]  # PX4 ends some with a tab


def _finish(out: Path, gcs: Px4Gcs, spec: Px4MissionSpec, figures: dict[str, Any], auto_t: float | None,
            daemon: subprocess.Popen | None) -> dict[str, Any]:
    ours = {"solo": "GPS_RAW_INT", "handover": "GPS2_RAW", "gnss": "(none)"}[spec.setup]
    gcs.write_tlog(out / "gcs.tlog")
    # SIH's first HIL_STATE_QUATERNIONs after boot carry lat = lon = 0: no truth yet
    log = [(t, m) for t, m in gcs.log if not (m.get_type() == TRUTH and m.lat == 0 and m.lon == 0)]
    figures.update(score(log, spec, auto_t, out, truth_kind=TRUTH, truth_lon="lon", ours_kind=ours,
                         cruise_mps=spec.cruise_speed))
    if daemon is not None:
        figures.update(sent_score(out / "daemon", spec, auto_t, out, truth_kind=TRUTH, truth_lon="lon"))
    texts = statustexts(gcs)
    px4_texts = [txt for _, comp, _, txt in texts if comp == M.MAV_COMP_ID_AUTOPILOT1]
    alarms = [txt for txt in px4_texts if any(w in txt.lower() for w in FAILSAFE_WORDS)]
    figures["failsafe"] = any("failsafe" in txt.lower() for txt in alarms)
    figures["failsafe_texts"] = alarms[-20:]
    figures["modes"] = _modes(gcs, auto_t if auto_t is not None else gcs.log[0][0] if gcs.log else 0.0)
    figures["daemon_exit"] = None if daemon is None else daemon.poll()
    figures["spec"] = asdict(spec)
    figures["statustext"] = [txt for _, _, _, txt in texts][-40:]  # PX4's and the daemon's
    figures["px4_statustext"] = px4_texts[-40:]
    (out / "result.json").write_text(json.dumps(figures, indent=2, default=float))
    return figures


def _kv(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    if not name or not value:
        raise argparse.ArgumentTypeError(f"{text!r}: NAME=VALUE")
    return name, float(value)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--px4", default=os.environ.get("PX4_SITL"), help="PX4 SITL binary (default $PX4_SITL)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--setup", choices=("solo", "handover", "gnss"), default="solo")
    ap.add_argument("--estimator", choices=("paper", "taco+"), default="taco+")
    ap.add_argument("--profile", help="daemon profile (default px4_rover; handover: px4_rover_gps2)")
    ap.add_argument("--laps", type=int, default=2)
    ap.add_argument("--side", type=float, default=60.0)
    ap.add_argument("--cruise-speed", type=float, default=3.0, help="RO_SPEED_LIM, m/s")
    ap.add_argument("--gnss-off-after", type=float, default=30.0)
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--gcs-origin", action=argparse.BooleanOptionalAction, default=None,
                    help="the ground station sets EKF2's origin at home (default: solo only)")
    ap.add_argument("--params-file", default="auto",
                    help="QGroundControl parameter file for PX4 (default: the shipped px4_rover_<setup>.params; "
                         "'' for none)")
    ap.add_argument("--param", type=_kv, action="append", default=[], metavar="NAME=VALUE",
                    help="PX4 parameter at boot (repeatable)")
    ap.add_argument("--daemon-arg", action="append", default=[], help="extra `taco-mav run` argument (repeatable)")
    ap.add_argument("--restart-after", type=float, help="SIGTERM the daemon this many seconds after AUTO.MISSION "
                                                          "and start it again with the same command")
    a = ap.parse_args()
    if not a.px4 or not Path(a.px4).exists():
        print("px4_mission: error: --px4 (or $PX4_SITL) must name the PX4 SITL binary", file=sys.stderr)
        return 2
    spec = Px4MissionSpec(side_m=a.side, laps=a.laps, cruise_speed=a.cruise_speed, setup=a.setup,
                          gnss_off_after_s=a.gnss_off_after, estimator=a.estimator,
                          profile=a.profile or ("px4_rover_gps2" if a.setup == "handover" else "px4_rover"),
                          timeout_s=a.timeout, gcs_sets_origin=a.gcs_origin, extra_params=dict(a.param),
                          daemon_args=a.daemon_arg, params_file=a.params_file, restart_after_s=a.restart_after)
    res = run_px4_mission(Path(a.px4), Path(a.out), spec)
    hidden = ("spec", "statustext", "px4_statustext", "modes", "px4_params")
    print(json.dumps({k: v for k, v in res.items() if k not in hidden}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
