"""Closed loop on a real autopilot (docs/sitl.md): ArduPilot Rover SITL steered by what taco-mav sends.

Runs only where `ARDUROVER` names a SITL binary (build it with ../shared/tools/build_ardupilot_sitl.sh); each
mission takes about 4 minutes of real time. taco_mav.closedloop.ardupilot is the harness (`taco-mav mission
--autopilot ardupilot`, `tools/sitl_mission.py` are its command lines)."""

import os
from pathlib import Path

import pytest

from taco_mav.closedloop.ardupilot import MissionSpec, run_mission
from taco_mav.closedloop.scoring import accuracy_failures, daemon_summary

ARDUROVER = os.environ.get("ARDUROVER")
pytestmark = [pytest.mark.sitl, pytest.mark.skipif(
    not (ARDUROVER and Path(ARDUROVER).is_file()),
    reason="ArduPilot Rover SITL not available: set ARDUROVER to a build of ../shared/tools/build_ardupilot_sitl.sh")]


def _check(res: dict, spec: MissionSpec) -> None:
    assert res["mission_completed"], res
    assert res["ekf_rms_m"] <= 3.0, res  # SITL's own GPS: 0.36 m
    assert res["true_speed_max_mps"] <= 1.5 * spec.wp_speed, res  # no runaway
    # what we reported covered what we had, scored where we sent it
    assert not accuracy_failures(res), (accuracy_failures(res), res)


def test_square_mission_on_taco_mav_alone(tmp_path):
    spec = MissionSpec(setup="solo")
    _check(run_mission(Path(ARDUROVER), tmp_path, spec), spec)


def test_handover_mission_completes_after_gnss_is_lost(tmp_path):
    spec = MissionSpec(setup="handover", profile="ardupilot_rover_gps2", gnss_off_after_s=30.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _check(res, spec)
    assert res["gnss_off_after_auto_s"] is not None


def test_square_mission_on_a_3d_world_with_the_shipped_profile(tmp_path):
    """The camera sees a 3-D world (facades, trees, cars, another day's aerial map georeferenced ~1 m
    off; the square kept clear of buildings), the daemon runs the shipped `ardupilot_rover` profile as a user
    would. Without its map-error model: 2 fixes accepted, lock lost by count of weak answers, EKF failsafe 70 s into
    the mission. With it: EKF3 0.96-1.31 m RMS over three runs (docs/sitl.md; on cores loaded by other missions
    the daemon can fall behind and the bounds fail: one run at load average 6-8, 8.7 m)."""
    spec = MissionSpec(setup="solo", realism="3d")
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    assert res["mission_completed"], res
    assert res["ekf_rms_m"] <= 1.5, res
    assert res["true_speed_max_mps"] <= 1.5 * spec.wp_speed, res
    assert not accuracy_failures(res), (accuracy_failures(res), res)


@pytest.mark.nightly
def test_paper_mode_never_runs_away(tmp_path):
    spec = MissionSpec(setup="solo", estimator="paper", laps=1, timeout_s=150.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    # paper mode's honest 1-sigma (about 6 m at rest, between fixes) is refused by EKF3's GPS checks (horizontal
    # accuracy under 5 m for 10 s before it aligns), or it completes: never a runaway
    assert res["true_speed_max_mps"] is None or res["true_speed_max_mps"] <= 1.5 * spec.wp_speed, res
    assert res.get("verdict") != "runaway_stopped", res
    if res.get("verdict") == "ekf_never_ready":  # refused: for that reason, and what we sent was honest
        assert not any("is using GPS" in t for t in res["statustext"]), res
        assert res["ours_hacc_median_m"] > 5.0 and res["ours_sent_within_2_hacc"] >= 0.95, res


@pytest.mark.nightly
def test_daemon_restarted_mid_mission_keeps_the_rover_on_track(tmp_path):
    """The daemon stopped with SIGTERM 60 s into AUTO (solo, no --origin, EKF origin from the ground
    station) and started again with the same command starts where the autopilot's position puts the rover; the
    mission completes with EKF3 within 3 m of the truth throughout (a daemon that started again at the origin: 58 m,
    a runaway at 7.6 m/s)."""
    spec = MissionSpec(setup="solo", restart_after_s=60.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _check(res, spec)
    assert res["daemon_restarted_after_auto_s"] is not None and res["ekf_max_m"] <= 3.0, res


def _fault_check(res: dict, spec: MissionSpec, speed: bool = True) -> None:
    """A fault run: the mission completes, or the autopilot was told in time and stopped the rover (our fix type
    and accuracy made its EKF fail safe: HOLD), never a runaway; what we reported covered what we had throughout.
    speed False: the true top speed is left to the caller."""
    assert res.get("verdict") != "runaway_stopped", res
    assert res["true_speed_max_mps"] is not None, res
    assert not speed or res["true_speed_max_mps"] <= 1.5 * spec.wp_speed, res
    assert res["fault_started_after_auto_s"] is not None and res["fault_ended_after_auto_s"] is not None, res
    assert res["mission_completed"] or any("EKF failsafe" in t for t in res["statustext"]), res
    assert not accuracy_failures(res), (accuracy_failures(res), res)


@pytest.mark.nightly
def test_camera_frozen_then_black_mid_mission(tmp_path):
    """The camera's frames frozen for 10 s, then black for 10 s, 40 s into AUTO. Frozen and black frames
    are refused (no fix from a place the rover has left, no speed from a picture that does not move); on the IMU
    alone the rover profile's honest accuracy soon says the position is lost, our fix type drops and the
    autopilot's EKF fails safe (HOLD): a safe stop, reported, where the mission does not complete. Never a runaway:
    the matcher refuses the hung picture the camera-speed loop saw repeat (once taken as a fix 3 m back, which cost
    our speed 1 m/s for the rest of the outage), and the rover profile's tilt low-pass keeps EKF3's pitch, which
    leans towards our speed, out of it."""
    spec = MissionSpec(setup="solo", fault="camera", fault_after_s=40.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    # the true speed under 1.5 x WP_SPEED among the rest (4.8-5.3 m/s without the hung-picture refusal and the tilt
    # low-pass)
    _fault_check(res, spec)
    fixes, motion = res["daemon_fixes"], res["daemon_camera_motion"]
    assert fixes.get("frozen_frame", 0) >= 1 and fixes.get("blank_frame", 0) >= 1, fixes
    assert motion.get("frozen_frame", 0) >= 1, motion  # the camera-speed loop refuses them too


@pytest.mark.nightly
def test_matcher_worker_stalled_mid_mission(tmp_path):
    """The matcher's worker blocks for 30 s; after matcher_timeout_s the daemon abandons it, starts a
    fresh worker and the mission completes."""
    spec = MissionSpec(setup="solo", laps=1, fault="stall", fault_after_s=30.0, timeout_s=200.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _fault_check(res, spec)
    assert res["mission_completed"] and res["ekf_rms_m"] <= 3.0, res
    assert res["daemon_fixes"].get("matcher_timeout", 0) >= 1 and res["daemon_stuck_matchers"] is not None, res


@pytest.mark.nightly
def test_link_to_the_autopilot_cut_for_5_s(tmp_path):
    """Every byte between the daemon and the autopilot dropped for 5 s: the daemon notices the silence
    and carries its estimate over the gap with the uncertainty a 5 s gap at 3 m/s deserves (10 m: lock lost, fix
    type dropped, so EKF3 fails safe and holds), relocalises and tracks again; or the mission completes. Never a
    runaway, and the reports cover the error."""
    spec = MissionSpec(setup="solo", laps=1, fault="link", fault_after_s=30.0, timeout_s=200.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _fault_check(res, spec)
    assert res["fault_link_dropped_bytes"] > 0 and res["daemon_link_outages"] == 1, res


@pytest.mark.nightly
def test_receiver_glitches_while_it_steers(tmp_path):
    """Hand-over set-up (SITL's GNSS is GPS1 and steers the rover): the receiver jumps 20 m for 30 s
    (SITL's GPS glitch). Our guard rejects it at once and our GPS2 stays on camera and IMU with an accuracy that
    covers its error; the autopilot, which steers by GPS1, fails safe or completes, never a runaway."""
    spec = MissionSpec(setup="handover", profile="ardupilot_rover_gps2", laps=1, gnss_off_after_s=1e6,
                       fault="glitch", fault_after_s=30.0, timeout_s=200.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _fault_check(res, spec)
    assert res["daemon_events"].get("gnss_rejected", 0) >= 1, res["daemon_events"]


@pytest.mark.nightly
def test_receiver_dragged_slowly_while_it_steers(tmp_path):
    """Hand-over set-up: SITL's GNSS, GPS1, steering the rover, dragged east at 0.5 m/s for 40 s. Until
    the guard rejects it our GPS2 follows it, and the camera check every 5 s floors the accuracy we report at the
    camera's distance from the readings, so the reports cover the error throughout (without the floor: 6 m off with
    about 1 m reported, 8.2 times the accuracy); the autopilot fails safe or completes, never a runaway."""
    spec = MissionSpec(setup="handover", profile="ardupilot_rover_gps2", laps=1, gnss_off_after_s=1e6,
                       fault="spoof", fault_after_s=30.0, timeout_s=200.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _fault_check(res, spec)
    assert res["daemon_events"].get("gnss_rejected", 0) >= 1, res["daemon_events"]


def _never_follows(res: dict, spec: MissionSpec) -> None:
    """The bound for a camera that cannot read the ground (docs/sitl.md): no runaway; while the rover moves, EKF3 within
    max(3 m, 2x the accuracy we report) at least 95 % of the time; completed, or stopped by the autopilot's own
    failsafe."""
    assert res.get("verdict") != "runaway_stopped", res
    assert res["true_speed_max_mps"] is not None and res["true_speed_max_mps"] <= 1.5 * spec.wp_speed, res
    assert res["ekf_within_bound_moving_share"] is not None and res["ekf_within_bound_moving_share"] >= 0.95, res
    assert res["mission_completed"] or any("failsafe" in t.lower() for t in res["statustext"]), res


def test_a_camera_that_cannot_read_its_map_is_never_followed(tmp_path):
    """Hand-over set-up (SITL's GNSS steers until 30 s into AUTO, then only our GPS2): the daemon's map
    is another world's (seed 11) over the same ground, so every camera answer is wrong. None is fused (weak, or
    refused by the innovation gate while GNSS holds the track, or no better than chance once lock is lost); the
    ground station is told the camera is at chance before the rover moves, and once GNSS goes our accuracy says
    the position is lost, so EKF3 fails safe and holds. One run at d866902: EKF3 within bound 100 % of the time
    moving, no fix accepted, 104 weak, 4 at chance, EKF failsafe 12 s after GNSS went."""
    spec = MissionSpec(setup="handover", profile="ardupilot_rover_gps2", gnss_off_after_s=30.0, map_seed=11,
                       laps=1, timeout_s=200.0)
    res = run_mission(Path(ARDUROVER), tmp_path, spec)
    _never_follows(res, spec)
    fixes = daemon_summary(tmp_path / "daemon")["daemon_fixes"]
    assert fixes.get("accepted", 0) == 0 and fixes.get("weak", 0) + fixes.get("at_chance", 0) >= 10, fixes
    assert any("AT_CHANCE" in t for t in res["statustext"]), res["statustext"]

