"""Closed loop on ArduPilot Rover SITL driven by taco-mav (docs/sitl.md).

Starts `ardurover` (built by ../shared/tools/build_ardupilot_sitl.sh) on free TCP ports, the daemon
(`taco-mav run`, a subprocess exactly as a user starts it) on SITL's SERIAL1 with a camera rendered from a
synthetic world centred on SITL's home, uploads a square mission, arms, drives in AUTO and scores
(`taco_mav.closedloop.scoring`):
- the EKF's position (GLOBAL_POSITION_INT) against SITL's truth (SIMSTATE), metres;
- the rover's true speed (differentiated SIMSTATE) against WP_SPEED, m/s;
- our own output (the GPS instance that is ours, GPS_RAW_INT or GPS2_RAW) against the truth, with the
  horizontal accuracy we reported beside it (never again 1.2 m reported at 53 m).

Set-ups: `solo` (GPS1_TYPE=14: taco-mav is the only GPS) and `handover` (SITL's GNSS is GPS1 and steers the rover,
taco-mav is GPS2 with GPS2_TYPE=14; SIM_GPS1_ENABLE=0 part-way through the mission, so the EKF falls over to us).

`run_mission` writes OUT/result.json (the figures), OUT/truth.csv, ekf_error.csv, ours_error.csv, gcs.tlog (all
the ground station heard), the daemon's tlog and events in OUT/daemon/<UTC start time>/, and OUT/sitl/ (SITL's own
files). `taco-mav mission --autopilot ardupilot` and `tools/sitl_mission.py` are its command lines;
tests/test_sitl.py flies it when ARDUROVER is set.
"""

from __future__ import annotations

import json
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from taco_mav.closedloop import processes
from taco_mav.closedloop.faults import FaultRun
from taco_mav.closedloop.gcs import Gcs, M, arm, runaway, set_ekf_origin, wait_ekf
from taco_mav.closedloop.instances import reserved_instance
from taco_mav.closedloop.processes import log_tail, stop_group
from taco_mav.closedloop.scoring import score, sent_score, shadow_score
from taco_mav.closedloop.world import mission_world
from taco_mav.errors import ConfigError

HOME = (-35.363261, 149.165230, 584.0, 0.0)  # SITL's default (CMAC), lat, lon, alt m, heading deg
ROVER_AUTO, ROVER_HOLD = 10, 4
MODE_HOLD = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ROVER_HOLD)  # MAV_CMD_DO_SET_MODE's params for Rover's HOLD
SETUPS = ("solo", "handover")


# The age of our position when it reaches the autopilot, ms (docs/ardupilot.md: 20-50 ms, GPS1_DELAY_MS /
# GPS2_DELAY_MS). Left at 0, ArduPilot's MAV GPS driver assumes a receiver 200 ms behind, and EKF3 then places each
# of our fixes 200 ms in the past: 0.6 m at 3 m/s (EKF3 0.85 m RMS solo with it, 0.45 m at 20 ms, docs/sitl.md).
OUR_GPS_DELAY_MS = 20.0

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
    restart_after_s: float | None = None  # SIGTERM the daemon this long after AUTO and start it again
    daemon_args: tuple[str, ...] = ()  # more `taco-mav run` options (e.g. --record, --shadow)
    fault: str | None = None  # a fault on cue (faults.py: camera, stall, link, glitch, spoof)
    fault_after_s: float = 60.0  # ... this long after AUTO
    realism: str = "flat"  # the world the camera sees: flat (the mosaic painted on the ground) or 3d
    # the daemon's map is another world's mosaic (this seed) over the same ground: a camera that cannot read the
    # map it is given, every answer wrong; None: the world's own map
    map_seed: int | None = None
    # a 3-D world keeps its buildings, trees and cars off the square; False drives the square through them (issue
    # 37: the camera cannot read the ground for long stretches)
    keep_clear: bool = True


def default_profile(setup: str) -> str:
    """The daemon's shipped profile for a set-up: `ardupilot_rover_gps2` in hand-over (taco-mav is GPS2), else
    `ardupilot_rover`."""
    return "ardupilot_rover_gps2" if setup == "handover" else "ardupilot_rover"


def _instance_usable(inst: int) -> bool:
    """Whether instance -I inst's TCP ports 5760+10I .. 5763+10I are free."""
    for port in range(5760 + 10 * inst, 5764 + 10 * inst):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def read_parm_file(path: Path) -> dict[str, float]:
    """NAME -> value from an ArduPilot parameter file (.parm, as Mission Planner and MAVProxy save and load it:
    one `NAME VALUE` or `NAME,VALUE` per line, `#` comments, blank lines). A line that is neither is an error that
    names the file and the line."""
    out: dict[str, float] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        cols = text.replace(",", " ").split()
        try:
            if len(cols) != 2:
                raise ValueError
            out[cols[0]] = float(cols[1])
        except ValueError:
            raise ConfigError(f"{path}:{n}: {line.strip()!r}: expected NAME VALUE (an ArduPilot .parm line)") from None
    return out


def sitl_params(spec: MissionSpec) -> dict[str, float]:
    """SITL parameters of the set-up (written to a defaults file, so they hold from boot): our instance's delay is
    what docs/ardupilot.md tells a user to set (`OUR_GPS_DELAY_MS`)."""
    p: dict[str, float] = {"SERIAL1_PROTOCOL": 2, "SERIAL1_BAUD": 921, "WP_SPEED": spec.wp_speed,
                           "CRUISE_SPEED": spec.wp_speed}
    if spec.setup == "solo":
        p.update({"GPS1_TYPE": 14, "GPS2_TYPE": 0, "GPS_AUTO_SWITCH": 0, "GPS1_DELAY_MS": OUR_GPS_DELAY_MS})
    elif spec.setup == "handover":
        p.update({"GPS1_TYPE": 1, "GPS2_TYPE": 14, "GPS_AUTO_SWITCH": 4, "GPS_PRIMARY": 0,
                  "GPS2_DELAY_MS": OUR_GPS_DELAY_MS})
    else:
        raise ValueError(f"setup {spec.setup!r}: solo or handover")
    p.update(spec.extra_params)
    return p


def run_mission(ardurover: Path, out: Path, spec: MissionSpec, world: Path | None = None) -> dict[str, Any]:
    """Fly `spec` on SITL with taco-mav in the loop; returns the figures (also written to OUT/result.json). The
    SITL instance is one no other mission holds (`reserved_instance`), held until SITL has stopped."""
    out.mkdir(parents=True, exist_ok=True)
    world = world or mission_world(out, spec)
    with reserved_instance("ardurover", range(40), _instance_usable) as inst:
        return _fly(ardurover, out, spec, world, inst)


def _fly(ardurover: Path, out: Path, spec: MissionSpec, world: Path, inst: int) -> dict[str, Any]:
    """`run_mission` on SITL instance `inst`."""
    sitl_dir = out / "sitl"
    shutil.rmtree(sitl_dir, ignore_errors=True)
    sitl_dir.mkdir()
    defaults = ardurover.resolve().parents[3] / "Tools/autotest/default_params/rover.parm"
    extra = sitl_dir / "taco.parm"
    extra.write_text("".join(f"{k} {v}\n" for k, v in sitl_params(spec).items()))
    home = ",".join(str(v) for v in spec.home)
    sitl = subprocess.Popen([str(ardurover), "--model", "rover", "--speedup", "1", "-I", str(inst), "-w", "--home",
                             home, "--defaults", f"{defaults},{extra}"], cwd=sitl_dir,
                            stdout=open(sitl_dir / "out.log", "w"), stderr=subprocess.STDOUT, start_new_session=True)
    daemon = fault = None
    try:
        gcs = Gcs(5760 + 10 * inst)
        camera, port = f"world:{world}", 5762 + 10 * inst
        wrong_map = []
        if spec.map_seed is not None:
            other = mission_world(out / "other", replace(spec, world_seed=spec.map_seed))
            wrong_map = ["--map", str(other / json.loads((other / "world.json").read_text())["mosaic"])]
        if spec.fault is not None:
            fault = FaultRun(spec.fault, spec.fault_after_s, out, gcs, spec.home, spec.setup)
            camera, port = fault.camera(world), fault.connect_port(port)
        more = [f"--origin={spec.home[0]},{spec.home[1]},{spec.home[2]}"] if spec.daemon_origin else []
        daemon_cmd = processes.daemon_command(spec.profile, f"tcp:127.0.0.1:{port}", camera, out / "daemon",
                                              spec.estimator, more + wrong_map + list(spec.daemon_args))
        shutil.rmtree(out / "daemon", ignore_errors=True)
        daemon = processes.start(daemon_cmd, out / "daemon.log")
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
                daemon = processes.start(daemon_cmd, out / "daemon_restarted.log")
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
            if runaway(gcs, spec, hold=MODE_HOLD):
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
