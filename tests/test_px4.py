"""Closed loop on PX4: the SIH Ackermann rover (PX4 SITL, no Gazebo) steered by what taco-mav sends.

Runs only where `PX4_SITL` names a PX4 SITL binary (build it with ../shared/tools/build_px4_sitl.sh); each
mission takes about 3-4 minutes of real time and one PX4 instance (>= 3). taco_mav.closedloop.px4 is the
harness (`taco-mav mission --autopilot px4`, `tools/px4_mission.py` are its command lines); setup `gnss` is PX4's
own simulated receiver without the daemon, the baseline the others are held to."""

import os
from pathlib import Path

import pytest

from taco_mav.closedloop.px4 import Px4MissionSpec, run_px4_mission
from taco_mav.closedloop.scoring import accuracy_failures

PX4_SITL = os.environ.get("PX4_SITL")
pytestmark = [pytest.mark.px4, pytest.mark.skipif(
    not (PX4_SITL and Path(PX4_SITL).is_file()),
    reason="PX4 SITL not available: set PX4_SITL to a build of ../shared/tools/build_px4_sitl.sh")]


# What we reported covers what we had, scored where we sent it (`sent_score`). On PX4 SIH our error at send
# carries a bias that comes and goes between runs (0.3-0.6 m along the track, ahead of the truth, and 0.3-0.4 m
# to the right; none on ArduPilot), so 68-100 % of the reports fall within 2 sigma and 94-100 % within 3: the
# 3-sigma share and the largest ratio are held, the 2-sigma share is reported (the bias: docs/px4.md, a known limit).
PX4_COVERAGE = {"within_2": None, "within_3": 0.9, "max_ratio": 5.0}


def _check(res: dict, spec: Px4MissionSpec, ekf_rms_m: float) -> None:
    assert res["mission_completed"], res
    assert not res["failsafe"], res
    assert res["ekf_rms_m"] <= ekf_rms_m, res
    assert res["true_speed_max_mps"] <= 1.5 * spec.cruise_speed, res  # no runaway


@pytest.mark.nightly
def test_gnss_baseline_mission_completes(tmp_path):
    """PX4's own simulated receiver, no taco-mav: what the harness measures when the navigation is good
    (2 laps of the 60 m square at 3 m/s: about 0.35-0.5 m RMS)."""
    spec = Px4MissionSpec(setup="gnss")
    _check(run_px4_mission(Path(PX4_SITL), tmp_path, spec), spec, ekf_rms_m=1.0)


def test_square_mission_on_taco_mav_alone(tmp_path):
    """Airframe 10046: no simulated receiver, EKF2's only GNSS is the daemon's HIL_GPS."""
    spec = Px4MissionSpec(setup="solo")
    res = run_px4_mission(Path(PX4_SITL), tmp_path, spec)
    _check(res, spec, ekf_rms_m=3.0)
    assert not accuracy_failures(res, **PX4_COVERAGE), (accuracy_failures(res, **PX4_COVERAGE), res)


def test_handover_mission_completes_after_its_receiver_is_lost(tmp_path):
    """The simulated receiver steers; SIM_GPS_USED 0 after 30 s leaves the daemon's HIL_GPS, and PX4 must
    not fail safe (without a substitute it lands and disarms within seconds)."""
    spec = Px4MissionSpec(setup="handover", profile="px4_rover_gps2", gnss_off_after_s=30.0)
    res = run_px4_mission(Path(PX4_SITL), tmp_path, spec)
    _check(res, spec, ekf_rms_m=3.0)
    assert res["gnss_off_after_auto_s"] is not None
    assert res["disarmed_after_auto_s"] is None, res
    assert not accuracy_failures(res, **PX4_COVERAGE), (accuracy_failures(res, **PX4_COVERAGE), res)


@pytest.mark.nightly
def test_paper_mode_never_runs_away(tmp_path):
    spec = Px4MissionSpec(setup="solo", estimator="paper", laps=1, timeout_s=150.0)
    res = run_px4_mission(Path(PX4_SITL), tmp_path, spec)
    # paper mode's honest 1-sigma (about 6 m) is refused by EKF2's gates, or it completes: never a runaway
    assert res["true_speed_max_mps"] is None or res["true_speed_max_mps"] <= 1.5 * spec.cruise_speed, res
    assert res.get("verdict") != "runaway_stopped", res
