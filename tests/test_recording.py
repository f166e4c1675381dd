"""A recorded session evaluated offline (datasets/recording.py): the daemon beside the simulator over
UDP records mav.tlog and frames/ (GPS1 our echo, GPS2 a real receiver honest throughout); `taco-mav eval --tlog
--frames --map` then runs the same pipeline on the recording, scored against the receiver (never fused), with
the classical matcher on the world's mosaic. Also: an echo is never taken for truth; bad inputs are named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from taco_mav.cli import main
from taco_mav.config import Estimator, load_profile
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.daemon.record import RecordOptions
from taco_mav.datasets.recording import load_recording
from taco_mav.datasets.tlog import load_tlog
from taco_mav.errors import DataError
from taco_mav.sim import Simulator
from tests.sim_helpers import free_udp_port, play


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Simulator]:
    """40 s of a synthetic drive at 5x lockstep, taco+ with the classical matcher, --record at 5 Hz; returns
    (session folder, world folder, simulator)."""
    from taco_mav.datasets.synthetic import build_world

    tmp = tmp_path_factory.mktemp("recording")
    world = build_world(tmp / "w", seed=4, length_km=0.3, progress=False)
    port = free_udp_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=5.0, lockstep=True, wait_companion_s=10.0, drain_s=0.3,
                    duration_s=40.0, deny_after_s=float("inf"), gnss_noise_m=0.2, seed=1)
    log_dir = tmp / "session"
    daemon = Daemon(load_profile("synthetic"),
                    DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}", log_dir=log_dir,
                                  estimator=Estimator.TACO_PLUS, record=RecordOptions(rate_hz=5.0)),
                    clock=sim.clock, wall_clock=sim.utc_now)
    play(sim, daemon)
    return log_dir, world, sim


def test_truth_is_the_receiver_never_our_echo(session: tuple[Path, Path, Simulator]) -> None:
    log_dir, world, _ = session
    drive = load_recording(log_dir / "mav.tlog", log_dir / "frames", world / "mosaic.tif")
    assert drive.receiver == "GPS2_RAW"  # GPS_RAW_INT only repeats our GPS_INPUT
    assert len(drive.truth.t) >= 60 and len(drive.frame_times) >= 150
    assert drive.imu.t[0] <= drive.frame_times[0] and drive.frame_times[-1] <= drive.imu.t[-1]
    assert drive.frame(0).shape[2] == 3


def test_eval_on_the_recording_scores_against_the_receiver(session: tuple[Path, Path, Simulator],
                                                           tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log_dir, world, _ = session
    out = tmp_path / "run"
    rc = main(["-q", "eval", "--tlog", str(log_dir / "mav.tlog"), "--frames", str(log_dir / "frames"), "--map",
               str(world / "mosaic.tif"), "--profile", "synthetic", "--estimator", "taco+", "--matcher", "classical",
               "--out", str(out), "--no-plots"])
    assert rc == 0
    doc = json.loads((out / "results.json").read_text())
    (seq,) = doc["sequences"].values()
    fixes = [json.loads(line) for line in (out / log_dir.name / "fixes.jsonl").read_text().splitlines()]
    assert seq["ate_m"] <= 1.0, seq  # against a 0.2 m receiver (measured 0.31 m; dead reckoning 7.3 m)
    assert len(fixes) >= 3 and all(f["accepted"] for f in fixes)  # taco+ asks every 10 s: 40 s of drive
    # the survey: each answer against the receiver, and the verdict printed (too few answers for a verdict in 40 s)
    survey = seq["survey"]["drive"]
    assert survey["answers"] == survey["accepted"] == len(fixes) and survey["precision"] == 1.0, survey
    assert survey["median_error_m"] <= 1.0
    assert survey["verdict"] == ("usable" if len(fixes) >= 5 else "too few answers")
    assert f"camera fixes {survey['verdict'].replace('usable', 'usable here')}: {len(fixes)} of" in \
        capsys.readouterr().out
    again = tmp_path / "again"
    assert main(["-q", "eval", "--tlog", str(log_dir / "mav.tlog"), "--frames", str(log_dir / "frames"), "--map",
                 str(world / "mosaic.tif"), "--profile", "synthetic", "--estimator", "taco+", "--matcher",
                 "classical", "--out", str(again), "--no-plots"]) == 0
    timed = ("wall_s", "matcher_s_per_100m")  # what the machine's speed changes
    rerun = json.loads((again / "results.json").read_text())["sequences"]
    assert {k: v for k, v in next(iter(rerun.values())).items() if k not in timed} == \
        {k: v for k, v in seq.items() if k not in timed}  # deterministic


def test_an_echo_only_tlog_is_refused_by_name(tmp_path: Path, session: tuple[Path, Path, Simulator]) -> None:
    """A tlog whose only fixes repeat our GPS_INPUT (set-up A) has no truth: the error says which message."""
    from pymavlink import mavutil

    log_dir, _, _ = session
    src = mavutil.mavlink_connection(str(log_dir / "mav.tlog"))
    cut = tmp_path / "echo_only.tlog"
    with cut.open("wb") as f:
        while (m := src.recv_match()) is not None:
            if m.get_type() != "GPS2_RAW":
                f.write(int(m._timestamp * 1e6).to_bytes(8, "big") + m.get_msgbuf())
    with pytest.raises(DataError, match="GPS_RAW_INT only echo our GPS_INPUT"):
        load_tlog(cut)


def test_frames_of_another_session_are_refused(tmp_path: Path, session: tuple[Path, Path, Simulator]) -> None:
    log_dir, world, _ = session
    other = tmp_path / "frames"
    (other / "data").mkdir(parents=True)
    (other / "frames.csv").write_text("index,t_autopilot_s,t_companion_s,file\n0,1e6,0,data/0.jpg\n"
                                      "1,1.0000002e6,0,data/1.jpg\n")
    with pytest.raises(DataError, match="within the tlog's IMU span"):
        load_recording(log_dir / "mav.tlog", other, world / "mosaic.tif")
    assert np.isfinite(load_tlog(log_dir / "mav.tlog").truth.xy).all()


def test_recording_replayed_to_a_live_daemon(session: tuple[Path, Path, Simulator], tmp_path: Path) -> None:
    """`taco-mav sim --tlog` plays the recorded session as the autopilot, on the recorded clock, so a daemon with
    `--camera folder:SESSION/frames` reads the recorded frames at their own times: the replay's reports meet the
    rate rules and stay within 1.5 m of the recorded receiver (the truth here), from accepted camera fixes."""
    log_dir, world, _ = session
    port = free_udp_port()
    sim = Simulator(log_dir / "mav.tlog", f"udpout:127.0.0.1:{port}", speed=5.0, lockstep=True,
                    wait_companion_s=10.0, drain_s=0.3, gnss_noise_m=0.0)
    assert sim.drive.t0_autopilot is not None and sim.drive.duration_s >= 35.0
    daemon = Daemon(load_profile("synthetic"),
                    DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"folder:{log_dir / 'frames'}",
                                  map_path=world / "mosaic.tif", estimator=Estimator.TACO_PLUS),
                    clock=sim.clock, wall_clock=sim.utc_now)
    play(sim, daemon)
    assert sim.play_start == pytest.approx(sim.drive.t0_autopilot, abs=0.05)  # the recorded clock
    seq = sim.results()["sequences"][sim.drive.name]
    assert seq["gps_input_rate_hz"] >= 4.9 and seq["consecutive_gaps_over_245ms"] == 0
    assert seq["ate_m"] <= 1.5, seq
    assert daemon.summary()["fixes"].get("accepted", 0) >= 3
