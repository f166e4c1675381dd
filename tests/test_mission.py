"""`taco-mav mission` (taco_mav/commands/mission.py) without a simulator: the options build the same missions as the
harness's defaults, options of the other autopilot and bad values are refused before any work, and the scored
figures are written as JSON. The set-ups' autopilot parameters (closedloop.ardupilot.sitl_params,
closedloop.px4.px4_params) are checked here too; the missions themselves fly in tests/test_sitl.py and
tests/test_px4.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from taco_mav import cli
from taco_mav.closedloop import ardupilot, faults, px4
from taco_mav.commands import mission


def _args(*argv: str):
    return cli.build_parser().parse_args(["mission", *argv])


def test_the_parsers_names_agree_with_the_harness() -> None:
    assert mission.FAULTS == faults.KINDS
    assert mission.SETUPS == {"ardupilot": ardupilot.SETUPS, "px4": px4.SETUPS}


def test_the_defaults_are_the_harness_defaults() -> None:
    assert mission.mission_spec(_args("--autopilot", "ardupilot", "--out", "m.json")) == ardupilot.MissionSpec()
    assert mission.mission_spec(_args("--autopilot", "px4", "--out", "m.json")) == px4.Px4MissionSpec()
    hand = mission.mission_spec(_args("--autopilot", "ardupilot", "--out", "m.json", "--setup", "handover"))
    assert hand.profile == "ardupilot_rover_gps2"
    hand = mission.mission_spec(_args("--autopilot", "px4", "--out", "m.json", "--setup", "handover"))
    assert hand.profile == "px4_rover_gps2"


def test_options_reach_the_mission() -> None:
    spec = mission.mission_spec(_args("--autopilot", "ardupilot", "--out", "m.json", "--setup", "handover",
                                      "--wp-speed", "2", "--laps", "1", "--fault", "spoof", "--fault-after", "30",
                                      "--daemon-arg=--shadow", "--realism", "3d", "--through", "--map-seed", "11"))
    assert (spec.wp_speed, spec.laps, spec.fault, spec.fault_after_s, spec.daemon_args) == \
        (2.0, 1, "spoof", 30.0, ("--shadow",))
    assert (spec.realism, spec.keep_clear, spec.map_seed) == ("3d", False, 11)
    spec = mission.mission_spec(_args("--autopilot", "px4", "--out", "m.json", "--cruise-speed", "2.5",
                                      "--param", "EKF2_GPS_DELAY=40", "--no-gcs-origin", "--params-file", ""))
    assert (spec.cruise_speed, spec.extra_params, spec.gcs_sets_origin, spec.params_file) == \
        (2.5, {"EKF2_GPS_DELAY": 40.0}, False, "")


def test_an_ardupilot_parm_file_and_params_reach_the_mission(tmp_path: Path) -> None:
    """--params-file: an ArduPilot .parm (a path, or the name of one shipped beside the profiles), then each --param
    over it; both end in the SITL defaults file the mission boots with."""
    own = tmp_path / "rover.parm"
    own.write_text("# mine\nWENC_TYPE,1\n\nWENC_RADIUS 0.06  # measured\n")
    spec = mission.mission_spec(_args("--autopilot", "ardupilot", "--out", "m.json", "--params-file", str(own),
                                      "--param", "WENC_TYPE=10"))
    assert spec.extra_params == {"WENC_TYPE": 10.0, "WENC_RADIUS": 0.06}
    spec = mission.mission_spec(_args("--autopilot", "ardupilot", "--out", "m.json", "--params-file",
                                      "ardupilot_rover_wheels.parm", "--param", "WENC_TYPE=10",
                                      "--param", "WENC2_TYPE=10"))
    booted = ardupilot.sitl_params(spec)
    assert (booted["WENC_TYPE"], booted["WENC2_TYPE"], booted["WENC_POS_Y"], booted["WENC2_POS_Y"]) == \
        (10.0, 10.0, 0.15, -0.15)
    assert booted["SERVO11_FUNCTION"] == -1 and booted["GPS1_TYPE"] == 14


@pytest.mark.parametrize("argv, needle", [
    (["--autopilot", "px4", "--fault", "camera"], "--fault: ardupilot only"),
    (["--autopilot", "px4", "--daemon-origin"], "--daemon-origin: ardupilot only"),
    (["--autopilot", "ardupilot", "--param", "X=1", "--ardurover", "{T}/sitl", "--params-file", "{T}/none.parm"],
     "--params-file {T}/none.parm: no such file"),
    (["--autopilot", "ardupilot", "--ardurover", "{T}/sitl", "--params-file", "{T}/bad.parm"],
     "{T}/bad.parm:3: 'WENC_CPR': expected NAME VALUE"),
    (["--autopilot", "ardupilot", "--no-gcs-origin"], "--[no-]gcs-origin: px4 only"),
    (["--autopilot", "ardupilot", "--setup", "gnss"], "--setup gnss"),
    (["--autopilot", "ardupilot", "--fault", "glitch"], "--fault glitch: needs --setup handover"),
    (["--autopilot", "ardupilot", "--fault-after", "5"], "--fault-after: goes with --fault"),
    (["--autopilot", "ardupilot", "--laps", "0"], "--laps 0"),
    (["--autopilot", "px4", "--speed", "0"], "--speed 0"),
    (["--autopilot", "ardupilot", "--through"], "--through: goes with --realism 3d"),
    (["--autopilot", "ardupilot", "--ardurover", "{T}/no-such-binary"], "--ardurover {T}/no-such-binary: no such file"),
    (["--autopilot", "ardupilot", "--px4", "{T}/sitl"], "--px4: px4 only"),
    (["--autopilot", "ardupilot", "--ardurover", "{T}/sitl", "--profile", "nosuch"], "nosuch"),
    (["--autopilot", "px4", "--px4", "{T}/sitl", "--param", "X"], "--param X: expected NAME=VALUE"),
    (["--autopilot", "px4", "--px4", "{T}/sitl", "--params-file", "{T}/none.params"], "--params-file"),
    (["--autopilot", "ardupilot", "--ardurover", "{T}/sitl", "--run-dir", "{T}/done"], "already holds result.json"),
])
def test_bad_options_are_refused_before_any_work(tmp_path: Path, capsys: pytest.CaptureFixture, argv: list[str],
                                                 needle: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARDUROVER", raising=False)
    monkeypatch.delenv("PX4_SITL", raising=False)
    (tmp_path / "sitl").write_text("a binary")
    (tmp_path / "done").mkdir()
    (tmp_path / "bad.parm").write_text("# encoders\nWENC_TYPE 1\nWENC_CPR\n")
    (tmp_path / "done" / "result.json").write_text("{}")
    argv = [a.replace("{T}", str(tmp_path)) for a in argv]
    code = cli.main(["mission", "--out", str(tmp_path / "m.json"), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert err[-1].startswith("taco-mav mission: error: ") and needle.replace("{T}", str(tmp_path)) in err[-1], err
    assert not (tmp_path / "m.json").exists() and not (tmp_path / "m").exists()


def test_the_binary_comes_from_the_environment(tmp_path: Path, capsys: pytest.CaptureFixture,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PX4_SITL", raising=False)
    assert cli.main(["mission", "--autopilot", "px4", "--out", str(tmp_path / "m.json")]) == 2
    assert "--px4: required (or set $PX4_SITL)" in capsys.readouterr().err
    monkeypatch.setenv("PX4_SITL", str(tmp_path / "gone"))
    assert cli.main(["mission", "--autopilot", "px4", "--out", str(tmp_path / "m.json")]) == 2
    assert f"$PX4_SITL {tmp_path / 'gone'}: no such file" in capsys.readouterr().err


def test_the_scored_figures_are_written_as_json(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """The mission itself replaced by a stand-in: what the command hands it and what it writes."""
    (tmp_path / "ardurover").write_text("a binary")
    flown = {}

    def fake_run(binary: Path, out: Path, spec: ardupilot.MissionSpec) -> dict:
        flown.update(binary=binary, out=out, spec=spec)
        return {"mission_completed": True, "ekf_rms_m": 0.9, "spec": {"laps": spec.laps}, "statustext": ["x"]}

    monkeypatch.setattr(ardupilot, "run_mission", fake_run)
    code = cli.main(["mission", "--autopilot", "ardupilot", "--ardurover", str(tmp_path / "ardurover"), "--laps", "1",
                     "--out", str(tmp_path / "runs" / "solo.json")])
    assert code == 0
    assert flown["binary"] == tmp_path / "ardurover" and flown["out"] == tmp_path / "runs" / "solo"
    assert flown["spec"] == ardupilot.MissionSpec(laps=1)
    written = json.loads((tmp_path / "runs" / "solo.json").read_text())
    assert written == {"mission_completed": True, "ekf_rms_m": 0.9, "spec": {"laps": 1}, "statustext": ["x"]}
    shown = capsys.readouterr().out
    assert '"ekf_rms_m": 0.9' in shown and "statustext" not in shown and "wrote" in shown


def test_run_dir_beside_the_figures() -> None:
    assert mission.run_dir_for(Path("runs/solo.json")) == Path("runs/solo")
    assert mission.run_dir_for(Path("runs/solo")) == Path("runs/solo.run")


def test_ardupilot_parameters_of_each_setup() -> None:
    solo = ardupilot.sitl_params(ardupilot.MissionSpec(wp_speed=2.0, extra_params={"WP_RADIUS": 1.5}))
    assert solo["GPS1_TYPE"] == 14 and solo["GPS2_TYPE"] == 0 and solo["WP_SPEED"] == solo["CRUISE_SPEED"] == 2.0
    assert solo["WP_RADIUS"] == 1.5 and solo["GPS1_DELAY_MS"] == ardupilot.OUR_GPS_DELAY_MS == 20.0
    hand = ardupilot.sitl_params(ardupilot.MissionSpec(setup="handover"))
    assert (hand["GPS1_TYPE"], hand["GPS2_TYPE"], hand["GPS_AUTO_SWITCH"]) == (1, 14, 4)
    assert hand["GPS2_DELAY_MS"] == 20.0 and "GPS1_DELAY_MS" not in hand  # SITL's own receiver keeps its driver's
    with pytest.raises(ValueError, match="solo or handover"):
        ardupilot.sitl_params(ardupilot.MissionSpec(setup="gnss"))


def test_px4_parameters_of_each_setup(tmp_path: Path) -> None:
    solo = px4.px4_params(px4.Px4MissionSpec(cruise_speed=2.0))
    shipped = px4.read_params_file(px4.params_file(px4.Px4MissionSpec()))
    assert solo["RO_SPEED_LIM"] == 2.0 and all(solo[k] == v for k, v in shipped.items())
    assert px4.params_file(px4.Px4MissionSpec(setup="gnss")) is None
    assert px4.px4_params(px4.Px4MissionSpec(setup="gnss")) == {"RO_SPEED_LIM": 3.0}
    assert px4.px4_params(px4.Px4MissionSpec(setup="handover", params_file=""))["MAV_USEHILGPS"] == 1
    own = tmp_path / "own.params"
    own.write_text("# a comment\n1\t1\tEKF2_GPS_DELAY\t55\t9\n")
    assert px4.px4_params(px4.Px4MissionSpec(params_file=str(own), extra_params={"X": 1.0})) == \
        {"RO_SPEED_LIM": 3.0, "EKF2_GPS_DELAY": 55.0, "X": 1.0}
    with pytest.raises(ValueError, match="solo, handover or gnss"):
        px4.px4_params(px4.Px4MissionSpec(setup="duo"))
