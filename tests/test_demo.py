"""`taco-mav demo` (taco_mav/demo.py, commands/live.py): by default it runs what a rover runs (taco+, the classical
matcher, profile synthetic_rover) and its summary shows ArduPilot's acceptance checks met with their figures;
`--estimator paper` runs the paper's method (profile synthetic) and says in one line why EKF3 would refuse it.
The drive itself: tests/test_live.py::test_demo_short; the run folders and Ctrl-C: tests/test_cli.py."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path
from typing import Any

import pytest

from taco_mav import cli
from taco_mav.config import Estimator, load_profile

# results.json entries of two real default-world runs (`taco-mav demo --out /tmp/demo_x [--estimator paper]`),
# cut to what the summary prints
TACO_PLUS_RUN = {
    "ate_m": 0.379, "ate_unaligned_m": 0.379, "length_km": 1.22, "ate_m_per_km": 0.311, "ate_denied_m": 0.38,
    "max_error_denied_m": 0.971, "denied_from_s": 1.0, "gps_input_count": 992, "fix_type_counts": {"3": 992},
    "gps_input_rate_hz": 5.003, "gps_input_interval_p50_ms": 200.001, "gps_input_interval_p99_ms": 200.001,
    "gps_input_interval_max_ms": 200.001, "gps_input_interval_avg_ms": 199.899, "consecutive_gaps_over_245ms": 0,
    "gps_unhealthy_updates": 0, "gps_timeout": False, "ekf_gates_ok": True, "ekf_ready_after_s": 10.31,
    "ekf_gate_pass_fraction": 0.999, "hdop_p50": 0.5, "hdop_max": 0.764, "horiz_accuracy_p50_m": 0.915,
    "horiz_accuracy_max_m": 1.529, "satellites_min": 10, "speed_accuracy_max_mps": 0.851,
    "ekf_speed_accuracy_ok": True}
PAPER_RUN = {
    **TACO_PLUS_RUN, "ate_m": 1.373, "ate_unaligned_m": 1.373, "ate_m_per_km": 1.125, "ate_denied_m": 1.377,
    "max_error_denied_m": 3.438, "fix_type_counts": {"1": 2, "3": 990}, "ekf_gates_ok": False,
    "ekf_ready_after_s": None, "ekf_gate_pass_fraction": 0.064, "hdop_p50": 3.307, "hdop_max": 5.86,
    "horiz_accuracy_p50_m": 6.613, "horiz_accuracy_max_m": 11.72, "speed_accuracy_max_mps": 0.58}


def test_the_default_is_what_a_rover_runs() -> None:
    """taco+ with the classical matcher, profile synthetic_rover, GPS_INPUT at 5 Hz: the run_demo default and
    the command line's (which leaves --estimator unset and takes run_demo's)."""
    from taco_mav.demo import DEMO_ESTIMATOR, DEMO_PROFILES, demo_profile, run_demo

    assert DEMO_ESTIMATOR == "taco+" and inspect.signature(run_demo).parameters["estimator"].default == "taco+"
    assert cli.build_parser().parse_args(["demo"]).estimator is None
    assert DEMO_PROFILES == {"taco+": "synthetic_rover", "paper": "synthetic"}
    rover = load_profile(demo_profile("taco+"))
    assert rover.name == "synthetic_rover" and rover.estimator is Estimator.TACO_PLUS
    assert rover.matcher == "classical" and rover.output.messages == ("gps_input",) and rover.output.rate_hz == 5.0
    paper = load_profile(demo_profile("paper"))
    assert paper.name == "synthetic" and paper.estimator is Estimator.PAPER and paper.matcher == "classical"


def test_synthetic_rover_is_ardupilot_rover_through_the_worlds_camera() -> None:
    """Every setting of ardupilot_rover (taco+, answer check, IMU tilt low-pass, map offset, plus) but the camera
    and gyro noise (the synthetic world's, as profile synthetic has them) and the reported yaw (the simulator
    scores the track and would turn it by the first yaw's compass error)."""
    rover, demo, world = load_profile("ardupilot_rover"), load_profile("synthetic_rover"), load_profile("synthetic")
    differ = {f.name for f in dataclasses.fields(rover) if getattr(rover, f.name) != getattr(demo, f.name)}
    assert differ == {"name", "camera", "imu", "output"}
    assert demo.camera == world.camera and demo.imu.gyro_arw == world.imu.gyro_arw
    assert dataclasses.replace(demo.imu, gyro_arw=rover.imu.gyro_arw) == rover.imu
    assert dataclasses.replace(demo.output, send_yaw=True) == rover.output and not demo.output.send_yaw
    assert demo.answer.decoys == 3 and demo.map.georef_sigma_m == 1.0 and demo.imu.tilt_lowpass_s == 30.0


def test_demo_title_names_estimator_matcher_and_profile() -> None:
    from taco_mav.demo import demo_title

    title = demo_title("taco+", "classical", "synthetic_rover", TACO_PLUS_RUN)
    assert title == ("taco-mav demo (taco+, classical matcher, profile synthetic_rover): ATE 0.38 m over 1.22 km, "
                     "GNSS denied after the start")
    assert demo_title("paper", "classical", "synthetic", {"ate_m": None, "length_km": 0.0}).startswith(
        "taco-mav demo (paper, classical matcher, profile synthetic): ATE nan m")


def _summary(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path,
             argv: list[str], seq: dict[str, Any], fixes: dict[str, int]) -> tuple[list[str], str]:
    """The demo's printed summary for `argv` with run_demo replaced by one that returns `seq`; (lines, estimator
    run_demo was asked for)."""
    import taco_mav.demo as demo

    asked: list[str] = []

    def fake_run_demo(out: Path, progress: bool = True, speed: float = demo.DEMO_SPEED, duration_s: Any = None,
                      estimator: str = demo.DEMO_ESTIMATOR, force: bool = False) -> demo.DemoResult:
        asked.append(estimator)
        return demo.DemoResult(drive="2011_01_01_drive_0001", results=seq, results_path=out / "results.json",
                               plot_path=out / "trajectory.png", world_dir=out / "world", wall_s=50.0,
                               daemon={"fixes": fixes}, estimator=estimator, matcher="classical",
                               profile=demo.demo_profile(estimator))

    monkeypatch.setattr(demo, "run_demo", fake_run_demo)
    assert cli.main(["demo", "--out", str(tmp_path), *argv]) == 0
    return capsys.readouterr().out.splitlines(), asked[0]


def test_default_summary_shows_ardupilots_checks_met_with_figures(monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str],
                                                                  tmp_path: Path) -> None:
    lines, asked = _summary(monkeypatch, capsys, tmp_path, [], TACO_PLUS_RUN, {"accepted": 40, "rejected": 1})
    assert asked == "taco+"
    assert lines[0] == "estimator / matcher          taco+ / classical (profile synthetic_rover)"
    for line in ("ATE (first-pose aligned)     0.38 m",
                 "GPS_INPUT rate               5.00 Hz",
                 "AP_GPS timing                met (average interval 200 ms < 215; two gaps > 245 ms in a row 0 times)",
                 "EKF3 GPS checks (10 s)       met, in use 10.3 s after the first GPS_INPUT (99.9% of GPS_INPUT pass)",
                 "  HDOP p50 / max             0.50 / 0.76 (<= 2.5)",
                 "  accuracy p50 / max         0.92 / 1.53 m (<= 5 m)",
                 "  satellites (virtual) min   10 (>= 6)",
                 "  speed accuracy max         0.85 m/s (<= 1 m/s: met)",
                 "CVGL fixes accepted          40 of 41 answered"):
        assert line in lines, (line, lines)
    assert not [ln for ln in lines if "refuse" in ln or "NOT met" in ln], lines


def test_paper_summary_says_in_one_line_why_ekf3_refuses_it(monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str],
                                                            tmp_path: Path) -> None:
    lines, asked = _summary(monkeypatch, capsys, tmp_path, ["--estimator", "paper"], PAPER_RUN, {"accepted": 99})
    assert asked == "paper"
    assert lines[0] == "estimator / matcher          paper / classical (profile synthetic)"
    assert "EKF3 GPS checks (10 s)       NOT met (6.4% of GPS_INPUT pass)" in lines
    assert "  accuracy p50 / max         6.61 / 11.72 m (<= 5 m)" in lines
    refusal = [ln for ln in lines if "refuse" in ln]
    assert refusal == ["EKF3 would refuse paper mode its honest 1-sigma (p50 6.61 m) is over the 5 m EKF3 accepts "
                       "(HDOP p50 3.31 > 2.5)"]


@pytest.mark.parametrize("change,reason", [
    ({"satellites_min": 4, "hdop_p50": 1.0, "horiz_accuracy_p50_m": 2.0}, "4 satellites < 6"),
    ({"hdop_p50": 2.8, "horiz_accuracy_p50_m": 2.0}, "HDOP p50 2.80 > 2.5"),
    ({"gps_unhealthy_updates": 3, "hdop_p50": 1.0, "horiz_accuracy_p50_m": 2.0}, "AP_GPS's timing checks fail"),
    ({"hdop_p50": 1.0, "horiz_accuracy_p50_m": 2.0}, "its checks never held 10 s in a row (6% of GPS_INPUT pass)"),
])
def test_ekf3_refusal_names_the_failed_check(change: dict[str, Any], reason: str) -> None:
    from taco_mav.commands.live import ekf3_refusal

    assert ekf3_refusal(TACO_PLUS_RUN) is None
    assert ekf3_refusal({**PAPER_RUN, **change}) == reason
