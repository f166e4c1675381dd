import dataclasses
import math

import pytest

from taco_mav.config import (Estimator, Profile, load_profile, localiser_params, profile_from_dict, profile_to_dict,
                             replace_in)
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.params import PlusParams
from taco_mav.errors import ConfigError


def test_defaults_are_the_papers_values():
    p = Profile()
    assert (p.trigger.epsilon_m, p.trigger.time_s) == (1.0, 2.0)
    assert (p.trigger.forward_bias_k, p.trigger.forward_bias_cap_m, p.trigger.cross_k, p.trigger.cross_cap_m) == (0.4, 15.0, 0.5, 10.0)
    assert p.gate.yaw_residual_max_rad == 0.35
    assert (p.ukf.alpha, p.ukf.beta, p.ukf.kappa) == (1e-3, 2.0, 0.0)
    assert (p.ukf.fix_fwd_min_m, p.ukf.fix_fwd_max_m, p.ukf.fix_lat_min_m, p.ukf.fix_lat_max_m) == (0.5, 8.0, 1.0, 12.0)
    assert (p.smoother.lc_max_chord_m, p.smoother.lc_min_frame_gap, p.smoother.lc_min_path_ratio) == (50.0, 30, 5.0)
    assert (p.smoother.savgol_window, p.smoother.savgol_order, p.smoother.lm_max_iterations) == (15, 3, 100)
    assert p.error_model.cross_k == 3.0 and p.error_model.divergence_k == 0.03
    assert p.estimator is Estimator.PAPER


def test_localiser_params_are_the_profile_sections_themselves():
    """One definition per parameter: the core takes the profile's own section objects, and a bare
    LocaliserParams() / PlusParams() is exactly what a default profile runs (no twin with other defaults)."""
    prof = replace_in(Profile(), "gate.enabled", False)
    lp = localiser_params(prof)
    assert lp.gate.enabled is False
    for name in ("imu", "error_model", "trigger", "gate", "ukf", "smoother", "latency", "gnss"):
        assert getattr(lp, name) is getattr(prof, name), name
    assert lp.plus is None
    plus = replace_in(prof, "estimator", Estimator.TACO_PLUS)
    assert localiser_params(plus).plus is plus.plus
    assert LocaliserParams() == localiser_params(Profile())
    default_plus = localiser_params(replace_in(Profile(), "estimator", Estimator.TACO_PLUS))
    assert LocaliserParams(plus=PlusParams()) == default_plus


def test_shipped_profiles_load(tmp_path):
    p = load_profile("kitti")
    assert p.name == "kitti" and p.imu.gyro_arw == pytest.approx(5.8e-5)


@pytest.mark.parametrize("text,needle", [
    ("trigger:\n  epsilonm: 1.0\n", "trigger.epsilonm: unknown key"),
    ("gate:\n  yaw_residual_max_rad: wide\n", "gate.yaw_residual_max_rad: expected a number"),
    ("ukf:\n  alpha: -1\n", "ukf.alpha: -1.0 is out of range"),
    ("smoother:\n  lc_min_frame_gap: 2.5\n", "smoother.lc_min_frame_gap: expected an integer"),
    ("gate:\n  enabled: 1\n", "gate.enabled: expected true/false"),
    ("estimator: taco++\n", "estimator: 'taco++' is not one of"),
    ("matcher: sift\n", "matcher: 'sift' is not one of"),
    ("colour: red\n", "colour: unknown key"),
    ("- a\n- b\n", "must be a mapping"),
    ("trigger: [1, 2\n", "not valid YAML"),
    ("camera:\n  position_frd_m: [1.0, 0.2]\n", "camera.position_frd_m: expected a list of 3 values, got 2"),
    ("camera:\n  position_frd_m: 1.0\n", "camera.position_frd_m: expected a list"),
    ("camera:\n  position_frd_m: [1.0, x, 0]\n", "camera.position_frd_m[1]: expected a number"),
    ("camera:\n  position_frd_m: [108, 0, 0]\n", "camera.position_frd_m[0]: 108.0 is out of range"),
    ("output:\n  antenna_frd_m: [0, 0, 0, 0]\n", "output.antenna_frd_m: expected a list of 3 values, got 4"),
    ("output:\n  antenna_xyz: [0, 0, 0]\n", "output.antenna_xyz: unknown key"),
])
def test_bad_profiles_name_file_and_key(tmp_path, text, needle):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_profile(f)
    assert needle in str(exc.value)
    assert str(f) in str(exc.value)
    assert exc.value.exit_code == 2


def test_missing_profile():
    with pytest.raises(ConfigError, match="no such profile"):
        load_profile("no_such_vehicle")
    with pytest.raises(ConfigError, match="not found"):
        load_profile("/nonexistent/x.yaml")


def test_round_trip_through_a_dict():
    p = replace_in(Profile(), "ukf.anisotropic", False)
    assert profile_from_dict(profile_to_dict(p)) == p
    assert math.isclose(profile_to_dict(p)["ukf"]["alpha"], 1e-3)


def test_lever_arms_load_as_tuples_and_reach_the_localiser(tmp_path):
    """camera.position_frd_m and output.antenna_frd_m: body FRD lists of three numbers, default zero; the
    Localiser gets the camera's horizontal lever arm as (forward, left) = (x, -y)."""
    assert Profile().camera.position_frd_m == (0.0, 0.0, 0.0) and Profile().output.antenna_frd_m == (0.0, 0.0, 0.0)
    assert localiser_params(Profile()).camera_lever_fwd_left_m == (0.0, 0.0)
    f = tmp_path / "rover.yaml"
    f.write_text("camera:\n  position_frd_m: [0.8, -0.1, -0.6]\noutput:\n  antenna_frd_m: [-0.2, 0, -0.4]\n")
    p = load_profile(f)
    assert p.camera.position_frd_m == (0.8, -0.1, -0.6) and p.output.antenna_frd_m == (-0.2, 0.0, -0.4)
    assert localiser_params(p).camera_lever_fwd_left_m == (0.8, 0.1)
    assert profile_from_dict(profile_to_dict(p)) == p  # lists in the resolved config, tuples again on load


def test_the_wheels_profile_loads_and_reaches_the_localiser():
    p = load_profile("ardupilot_rover_wheels")
    base = load_profile("ardupilot_rover")
    assert p.wheels.enabled and p.wheels.pos_y_from_autopilot and p.wheels.wheel_pos_y_m == (0.15, -0.15)
    assert dataclasses.replace(p, name=base.name, wheels=base.wheels) == base  # ardupilot_rover plus `wheels:`
    assert localiser_params(p).wheels == p.wheels and localiser_params(base).wheels is None
    paper = localiser_params(dataclasses.replace(p, estimator=Estimator.PAPER))
    assert paper.plus is None  # paper mode: nothing reads the wheels
    hand, hand_base = load_profile("ardupilot_rover_gps2_wheels"), load_profile("ardupilot_rover_gps2")
    assert dataclasses.replace(hand, name=hand_base.name, wheels=hand_base.wheels) == hand_base
    assert hand.wheels == p.wheels and hand.output.gps_id == 1  # the same wheels, taco_mav as GPS2
