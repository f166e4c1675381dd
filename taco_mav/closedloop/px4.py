"""Closed loop on PX4: SIH (PX4's built-in simulator, no Gazebo) Ackermann rover driven by taco-mav.

The sibling of `taco_mav.closedloop.ardupilot` (ArduPilot Rover SITL), sharing its ground station, mission upload
and scoring. Starts PX4 SITL (built by ../shared/tools/build_px4_sitl.sh) as instance I >= 3 with a private
command folder and a fresh rootfs under OUT/px4 (`px4_sitl`), the daemon (`taco-mav run`, a subprocess exactly as
a user starts it) on PX4's onboard MAVLink link with a camera rendered from a synthetic world centred on SIH's
home (Zurich), uploads a square mission, arms, drives in AUTO.MISSION and scores:
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

`run_px4_mission` writes OUT/result.json (the figures), OUT/truth.csv, ekf_error.csv, ours_error.csv (as the
ArduPilot mission), gcs.tlog (all the ground station heard), the daemon's tlog and events in
OUT/daemon/<UTC start time>/, OUT/daemon.log, and OUT/px4/ (rootfs with PX4's log and parameters, out.log: its
console). `taco-mav mission --autopilot px4` and `tools/px4_mission.py` are its command lines; tests/test_px4.py
flies it when PX4_SITL is set.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from taco_mav.closedloop import processes
from taco_mav.closedloop.gcs import M, arm, runaway, set_ekf_origin, wait_ekf
from taco_mav.closedloop.instances import reserved_instance
from taco_mav.closedloop.processes import log_tail, stop_group
from taco_mav.closedloop.px4_sitl import (
    FIRST_INSTANCE,
    MISSION_STATE_ACTIVE,
    MISSION_STATE_COMPLETE,
    MODE_HOLD,
    MODE_MISSION,
    TRUTH,
    Px4Gcs,
    instance_usable,
    modes,
    read_params_file,
    set_mode,
    start_px4,
    statustexts,
)
from taco_mav.closedloop.scoring import score, sent_score
from taco_mav.closedloop.world import mission_world
from taco_mav.config import PROFILE_DIR

HOME = (47.397743, 8.545594, 488.9, 0.0)  # SIH's home (lat, lon, alt m AMSL, heading deg)
SETUPS = ("solo", "handover", "gnss")
MODELS = {"solo": "sihsim_rover_ackermann_extgps", "handover": "sihsim_rover_ackermann",
          "gnss": "sihsim_rover_ackermann"}
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
    realism: str = "flat"  # the world the camera sees (world.mission_world): flat or 3d
    keep_clear: bool = True  # a 3-D world keeps its buildings and trees off the square (world.mission_world)

    def sets_origin(self) -> bool:
        return self.setup == "solo" if self.gcs_sets_origin is None else self.gcs_sets_origin


def default_profile(setup: str) -> str:
    """The daemon's shipped profile for a set-up: `px4_rover_gps2` in hand-over (the daemon's HIL_GPS is a second
    receiver), else `px4_rover`."""
    return "px4_rover_gps2" if setup == "handover" else "px4_rover"


def params_file(spec: Px4MissionSpec) -> Path | None:
    """The parameter file spec.params_file names (see Px4MissionSpec), or None."""
    if spec.params_file == "auto":
        shipped = PROFILE_DIR / f"px4_rover_{spec.setup}.params"
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



def run_px4_mission(px4: Path, out: Path, spec: Px4MissionSpec, world: Path | None = None) -> dict[str, Any]:
    """Drive `spec` on PX4 SITL (SIH) with taco-mav in the loop (not in setup gnss); returns the figures (also
    written to OUT/result.json)."""
    px4_params(spec)  # refuses an unknown setup before anything starts
    out.mkdir(parents=True, exist_ok=True)
    if spec.setup != "gnss":
        world = world or mission_world(out, spec)
    with reserved_instance("px4", range(FIRST_INSTANCE, FIRST_INSTANCE + 40), instance_usable) as inst:
        return _drive_mission(px4, out, spec, world, inst)


def _drive_mission(px4: Path, out: Path, spec: Px4MissionSpec, world: Path | None, inst: int) -> dict[str, Any]:
    """`run_px4_mission` on PX4 instance `inst` (held by the caller until PX4 has stopped)."""
    proc = start_px4(px4, out / "px4", inst, MODELS[spec.setup], px4_params(spec))
    daemon = None
    figures: dict[str, Any] = {"instance": inst, "px4_params": px4_params(spec)}
    try:
        gcs = Px4Gcs(inst)
        t0 = time.time()
        if spec.setup != "gnss":
            daemon_cmd = processes.daemon_command(spec.profile, f"udpin:127.0.0.1:{14540 + inst}", f"world:{world}",
                                                  out / "daemon", spec.estimator, spec.daemon_args)
            shutil.rmtree(out / "daemon", ignore_errors=True)
            daemon = processes.start(daemon_cmd, out / "daemon.log")
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
            daemon = processes.start(daemon_cmd, out / "daemon_restarted.log")

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
        if runaway(gcs, spec, truth_kind=TRUTH, truth_lon="lon", hold=MODE_HOLD):
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
    figures["modes"] = modes(gcs, auto_t if auto_t is not None else gcs.log[0][0] if gcs.log else 0.0)
    figures["daemon_exit"] = None if daemon is None else daemon.poll()
    figures["spec"] = asdict(spec)
    figures["statustext"] = [txt for _, _, _, txt in texts][-40:]  # PX4's and the daemon's
    figures["px4_statustext"] = px4_texts[-40:]
    (out / "result.json").write_text(json.dumps(figures, indent=2, default=float))
    return figures

