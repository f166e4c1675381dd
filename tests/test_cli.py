"""The `taco-mav` command line: --version, global flags before or after the subcommand, negative
option values, logging through the progress bars, results folders refused unless --force, one timestamped
folder per daemon session, work kept on a late error (bench, drift), Ctrl-C -> 130 with what was played
written, and the names tables and plots carry. Bad-input sweep: tests/test_cli_errors.py."""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import subprocess
import sys
import time
import types
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from taco_mav import cli
from taco_mav.cli_support import configure_logging
from taco_mav.errors import TacoError, UsageError


def _cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "taco_mav.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_version_is_the_distribution_version() -> None:
    from importlib.metadata import version

    res = _cli("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"taco-mav {version('taco_mav')}", res


@pytest.mark.parametrize("argv", [["-q", "--debug", "bench", "--out", "x.json"],
                                  ["bench", "--out", "x.json", "-q", "--debug"],
                                  ["--debug", "bench", "-q", "--out", "x.json"]])
def test_global_flags_before_or_after_the_subcommand(argv: list[str]) -> None:
    args = cli.build_parser().parse_args(argv)
    assert args.quiet is True and args.debug is True and args.verbose == 0 and args.command == "bench"


def test_verbose_counts_and_is_not_reset_by_the_subcommand() -> None:
    parse = cli.build_parser().parse_args
    assert parse(["-v", "demo"]).verbose == 1
    assert parse(["demo", "-vv"]).verbose == 2
    assert parse(["demo"]).verbose == 0 and parse(["demo"]).quiet is False


@pytest.mark.parametrize("flags, command, level", [
    ((False, 0, False), "bench", logging.INFO), ((True, 0, False), "bench", logging.WARNING),
    ((False, 1, False), "bench", logging.DEBUG), ((False, 0, True), "bench", logging.DEBUG),
    ((False, 0, False), "demo", logging.ERROR), ((True, 0, False), "demo", logging.ERROR),
    ((False, 1, False), "demo", logging.INFO), ((False, 2, False), "demo", logging.DEBUG)])
def test_log_levels(flags: tuple[bool, int, bool], command: str, level: int) -> None:
    """The demo is quiet by default (a progress bar, errors, its summary); -v adds a step of log; -q and --debug
    win. Other libraries show warnings only (everything with --debug); Python warnings only with -v."""
    root = logging.getLogger()
    saved = (root.handlers[:], root.level)
    try:
        handler = configure_logging(*flags, quiet_by_default=command in cli.QUIET_BY_DEFAULT)
        assert handler in root.handlers and handler.level == level and root.level == level

        def shown(name: str, levelno: int) -> bool:
            return levelno >= handler.level and handler.filter(logging.LogRecord(name, levelno, "", 0, "m", (), None))

        assert shown("taco_mav.daemon.daemon", level) and not shown("taco_mav.daemon.daemon", level - 10)
        assert shown("rasterio._env", logging.ERROR)
        assert shown("rasterio._env", logging.WARNING) == (level <= logging.WARNING)
        assert shown("rasterio._env", logging.INFO) == flags[2]
        assert shown("py.warnings", logging.WARNING) == (flags[1] > 0 or flags[2])
        assert sum(isinstance(h, type(handler)) for h in root.handlers) == 1  # a second call replaces ours
    finally:
        root.handlers[:] = saved[0]
        root.setLevel(saved[1])
        logging.captureWarnings(False)


def test_log_records_go_through_tqdm_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """A record printed while a bar runs goes through tqdm.write, which clears and redraws the bar."""
    import tqdm

    from taco_mav.progress import TqdmHandler

    written: list[str] = []
    monkeypatch.setattr(tqdm.tqdm, "write", classmethod(lambda cls, s, file=None, **kw: written.append(s)))
    logger = logging.getLogger("taco_mav.test_cli_handler")
    handler = TqdmHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    logger.addHandler(handler)
    logger.propagate = False
    try:
        logger.warning("fix rejected: %s", "yaw_gate")
    finally:
        logger.removeHandler(handler)
    assert written == ["WARNING fix rejected: yaw_gate"]


@pytest.mark.parametrize("argv, attr, value", [
    (["world", "--out", "w", "--centre", "-35.363261,149.165230"], "centre", "-35.363261,149.165230"),
    (["run", "--profile", "p", "--connect", "udpin:0.0.0.0:1", "--origin", "-35.36,149.16,584"], "origin",
     "-35.36,149.16,584"),
    (["sim", "--drive", "d", "--connect", "c", "--out", "o", "--home", "-35.36,-149.16,-3"], "home",
     "-35.36,-149.16,-3"),
    (["sim", "--drive", "d", "--connect", "c", "--out", "o", "--speed", "-2"], "speed", -2.0),
    (["world", "--out", "w", "--centre=-1.5,2"], "centre", "-1.5,2")])
def test_negative_option_values_parse(argv: list[str], attr: str, value: object) -> None:
    args = cli.build_parser().parse_args(cli.checks.join_negative_values(argv))
    assert getattr(args, attr) == value


def test_world_in_the_southern_hemisphere(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`world --centre -35.36,149.17` (no '=') builds a world there: UTM zone 55 south; 3-D by default (no
    --realism), its aerial map with a georeferencing offset of about a metre, and the profile to run it named."""
    assert cli.main(["world", "-q", "--out", str(tmp_path / "w"), "--centre", "-35.363261,149.165230",
                     "--length-km", "0.06"]) == 0
    meta = json.loads((tmp_path / "w" / "world.json").read_text())
    assert meta["centre"] == [-35.363261, 149.165230] and meta["crs_epsg"] == 32755
    assert meta["realism"] == "3d" and 0.8 <= math.hypot(*meta["aerial"]["georef_offset_m"]) <= 1.2
    assert "(3d; run it with --profile synthetic_3d --estimator taco+)" in capsys.readouterr().out
    from taco_mav.commands.live import world_profile_hint
    from taco_mav.config import load_profile

    hint = world_profile_hint(tmp_path / "w", load_profile("synthetic"))  # `taco-mav run` logs it as a warning
    assert hint is not None and "profile synthetic takes the map as exact" in hint and "synthetic_3d" in hint
    assert world_profile_hint(tmp_path / "w", load_profile("synthetic_3d")) is None


def test_world_along_a_real_drive_is_flat_by_default(kitti_root: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """`world --along-drive` has no 3-D layer yet: without --realism it builds a flat world and says so."""
    drive = kitti_root / "2011_09_26" / "2011_09_26_drive_0005_sync"
    assert cli.main(["world", "-q", "--out", str(tmp_path / "w"), "--along-drive", str(drive)]) == 0
    assert json.loads((tmp_path / "w" / "world.json").read_text())["realism"] == "flat"
    assert "(flat; run it with --profile synthetic)" in capsys.readouterr().out


def test_names_agree_with_the_library() -> None:
    from taco_mav.config import Estimator
    from taco_mav.cvgl.registry import MATCHERS
    from taco_mav.datasets.synthetic.imu_model import PRESETS

    assert set(cli.ESTIMATORS) == {e.value for e in Estimator}
    assert set(cli.MATCHERS) == set(MATCHERS)
    assert set(cli.IMU_PRESETS) == set(PRESETS)


# ---------------------------------------------------------------- results folders


def test_world_refuses_an_existing_world_unless_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "w"
    flat = ["--realism", "flat", "--length-km", "0.06"]
    assert cli.main(["world", "-q", "--out", str(out), "--seed", "1", *flat]) == 0
    before = (out / "world.json").read_text()
    assert cli.main(["world", "-q", "--out", str(out), "--seed", "2", *flat]) == 2
    assert f"--out {out}: already holds world.json" in capsys.readouterr().err
    assert (out / "world.json").read_text() == before
    assert cli.main(["world", "-q", "--out", str(out), "--seed", "2", *flat, "--force"]) == 0
    assert json.loads((out / "world.json").read_text())["seed"] == 2


def test_demo_run_folders_are_named_by_what_made_them(tmp_path: Path) -> None:
    from taco_mav.demo import _prepare, demo_run_dir

    assert demo_run_dir(tmp_path, "paper", "classical") == tmp_path / "paper-classical"
    assert demo_run_dir(tmp_path, "taco+", "classical") == tmp_path / "taco+-classical"
    run, profile = _prepare(tmp_path, 8.0, "paper", force=False)
    assert run == tmp_path / "paper-classical" and run.is_dir() and profile.matcher == "classical"
    assert profile.name == "synthetic"  # paper mode runs the paper's profile; taco+ the rover's
    assert _prepare(tmp_path, 8.0, "taco+", force=False)[1].name == "synthetic_rover"
    (run / "results.json").write_text("{}")
    (run / "trajectory.png").write_bytes(b"png")
    (run / "daemon").mkdir()
    (run / "daemon" / "events.jsonl").write_text("{}\n")
    with pytest.raises(UsageError, match="paper-classical: already holds results.json.*--force"):
        _prepare(tmp_path, 8.0, "paper", force=False)
    assert _prepare(tmp_path, 8.0, "taco+", force=False)[0] == tmp_path / "taco+-classical"  # the paper run stays
    assert (run / "results.json").exists()
    _prepare(tmp_path, 8.0, "paper", force=True)
    assert sorted(p.name for p in run.iterdir()) == []  # the earlier run's files are gone, nothing else touched
    assert (tmp_path / "taco+-classical").is_dir()


def test_demo_world_is_made_again_when_cut_short(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A demo world whose mosaic is truncated (Ctrl-C or a full disk while it was written) is generated again;
    a complete one is reused."""
    import taco_mav.datasets.synthetic as synthetic
    from taco_mav.demo import DEMO_SEED, demo_world
    from tests.test_cli_errors import write_geotiff

    built: list[Path] = []
    monkeypatch.setattr(synthetic, "build_world", lambda out, **kw: built.append(Path(out)) or Path(out))
    world = tmp_path / "world"
    world.mkdir()
    (world / "world.json").write_text(json.dumps({"seed": DEMO_SEED, "mosaic": "mosaic.tif"}))
    data = write_geotiff(tmp_path / "full.tif").read_bytes()
    (world / "mosaic.tif").write_bytes(data[: len(data) // 2])
    assert demo_world(tmp_path, progress=False) == world and built == [world]
    (world / "mosaic.tif").write_bytes(data)
    assert demo_world(tmp_path, progress=False) == world and built == [world]  # reused: not built again


def test_demo_checks_speed_before_any_work(tmp_path: Path) -> None:
    from taco_mav.demo import run_demo

    with pytest.raises(UsageError, match="--speed 0"):
        run_demo(tmp_path / "d", speed=0.0)
    assert not (tmp_path / "d").exists()


# ---------------------------------------------------------------- daemon log sessions


def test_session_dir_is_new_for_every_session(tmp_path: Path) -> None:
    from taco_mav.mavlink.appendlog import session_dir

    now = datetime(2026, 1, 24, 8, 15, 0, tzinfo=timezone.utc)
    first = session_dir(tmp_path / "logs", now)
    second = session_dir(tmp_path / "logs", now)  # started within the same second
    later = session_dir(tmp_path / "logs", datetime(2026, 1, 24, 9, 0, 1, tzinfo=timezone.utc))
    assert [p.name for p in (first, second, later)] == ["20260124T081500Z", "20260124T081500Z-2",
                                                        "20260124T090001Z"]
    assert all(p.is_dir() and not any(p.iterdir()) for p in (first, second, later))


def _run_daemon_once(log_root: Path) -> tuple[int, str]:
    from mav_autopilot import free_udp_port

    before = set(log_root.glob("*/events.jsonl")) if log_root.exists() else set()
    proc = subprocess.Popen([sys.executable, "-m", "taco_mav.cli", "run", "--profile", "ardupilot_rover",
                             "--dead-reckoning", "--connect", f"udpin:127.0.0.1:{free_udp_port()}",
                             "--log-dir", str(log_root)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and set(log_root.glob("*/events.jsonl")) == before:
            time.sleep(0.1)
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(15)
    finally:
        if proc.poll() is None:
            proc.kill()
    return rc, proc.stdout.read().decode()


def test_each_run_session_logs_into_its_own_folder(tmp_path: Path) -> None:
    """Two `run --log-dir L` sessions: two timestamped folders, each with one start and one stop."""
    logs = tmp_path / "logs"
    for _ in range(2):
        rc, out = _run_daemon_once(logs)
        assert rc == 0, out
        time.sleep(1.1)  # a new second: a new stamp (same-second starts get -2, see above)
    sessions = sorted(p for p in logs.iterdir())
    assert len(sessions) == 2 and all(len(p.name) == 16 and p.name.endswith("Z") for p in sessions)
    for s in sessions:
        kinds = [json.loads(ln)["event"] for ln in (s / "events.jsonl").read_text().splitlines()]
        assert kinds.count("start") == 1 and kinds[-1] == "stop"
        assert (s / "config.yaml").is_file() and (s / "mav.tlog").is_file()


# ---------------------------------------------------------------- work kept on a late error


def _fake_section(keys: dict[str, float] | None) -> types.ModuleType:
    mod = types.ModuleType("fake")

    def run(progress: bool) -> dict[str, float]:
        if keys is None:
            raise RuntimeError("the GPU went away")
        return dict(keys)

    mod.run = run  # type: ignore[attr-defined]
    return mod


def test_bench_keeps_what_it_measured_before_a_failing_section(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    import taco_mav.bench as bench

    mods = {"x.alpha": _fake_section({"alpha_ms": 1.5}), "x.beta": _fake_section(None),
            "x.gamma": _fake_section({"gamma_ms": 2.0})}
    monkeypatch.setattr(bench, "SECTIONS", tuple(mods))
    monkeypatch.setattr(bench, "SECTION_NAMES", ("alpha", "beta", "gamma"))
    monkeypatch.setattr(bench.importlib, "import_module", lambda name: mods[name])
    out = tmp_path / "bench.json"
    with pytest.raises(TacoError, match="bench section beta: RuntimeError: the GPU went away"):
        bench.run_bench(out, progress=False)
    assert json.loads(out.read_text()) == {"alpha_ms": 1.5}
    with pytest.raises(UsageError, match="--only delta"):
        bench.run_bench(tmp_path / "other.json", only=["alpha", "delta"], progress=False)
    assert not (tmp_path / "other.json").exists()
    assert bench.run_bench(out, only=["gamma"], progress=False) == {"gamma_ms": 2.0}


def _drift_tlog(path: Path) -> Path:
    from taco_mav.reliability.soak import circle_drive
    from tests.sim_helpers import write_tlog

    d = circle_drive(90.0, rate_hz=10.0, radius_m=150.0, speed_mps=8.0)
    d.accel_frd[:, 0] += np.random.default_rng(3).standard_normal(len(d)) * 0.05 / math.sqrt(0.1)
    return write_tlog(path, d)


def test_drift_reads_every_input_before_measuring(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A bad second tlog is found before the first is measured (nothing written); a failure while measuring
    the second drive keeps the first one's figures in --out."""
    import taco_mav.evaluation.drift as drift

    good = _drift_tlog(tmp_path / "rover.tlog")
    bad = tmp_path / "bad.tlog"
    bad.write_bytes(np.random.default_rng(1).integers(0, 255, 4000, dtype=np.uint8).tobytes())
    out = tmp_path / "drift.json"
    measured: list[str] = []
    real = drift.measure_drift

    def measure(d, **kw):
        measured.append(d.name)
        if len(measured) == 2:
            raise RuntimeError("measuring failed")
        return real(d, **kw)

    monkeypatch.setattr(drift, "measure_drift", measure)
    argv = ["drift", "-q", "--tlog", str(good), "--tlog", "TLOG2", "--profile", "ardupilot_rover", "--out", str(out)]
    rc = cli.main([str(bad) if a == "TLOG2" else a for a in argv])
    assert rc == 1 and f"taco-mav drift: error: {bad}" in capsys.readouterr().err
    assert measured == [] and not out.exists()
    rc = cli.main([str(_drift_tlog(tmp_path / "second.tlog")) if a == "TLOG2" else a for a in argv])
    assert rc == 1 and "measuring failed" in capsys.readouterr().err
    (rep,) = json.loads(out.read_text())["drives"]
    assert measured == ["rover", "second"]
    assert rep["drive"] == "rover" and rep["q_speed_mps"] == pytest.approx(0.05, rel=0.3)


# ---------------------------------------------------------------- Ctrl-C


def _sigint_default() -> None:
    """In the child before exec: SIGINT back to its default. A suite started in the background of a
    non-interactive shell (`nohup ... &`) ignores SIGINT, a child inherits that, and Python then installs no
    KeyboardInterrupt handler: the demo would never see the Ctrl-C."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_in_the_demo_exits_130_and_writes_what_was_played(tmp_path: Path) -> None:
    """SIGINT once the drive is playing: exit 130, no traceback, the summary says interrupted and the run
    folder holds the scoring of what was played."""
    out = tmp_path / "demo"
    # real time: the ~150 s drive outlasts the 8 s below by far however loaded the machine
    proc = subprocess.Popen([sys.executable, "-m", "taco_mav.cli", "demo", "-q", "--out", str(out), "--speed", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"), preexec_fn=_sigint_default)
    run = out / "taco+-classical"  # the default: taco+, what a rover runs
    try:
        deadline = time.monotonic() + 240
        events = run / "daemon" / "events.jsonl"
        while time.monotonic() < deadline and '"event": "origin"' not in (events.read_text()
                                                                           if events.exists() else ""):
            time.sleep(0.2)  # the daemon flushes its events every second
        assert proc.poll() is None, f"the demo ended (exit {proc.returncode}) before its daemon logged the origin"
        time.sleep(8.0)  # the drive is playing (GNSS denied after 1 s)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stdout + stderr
    assert "(interrupted)" in stdout and stderr.strip().splitlines()[-1] == "taco-mav demo: interrupted"
    doc = json.loads((run / "results.json").read_text())
    (seq,) = doc["sequences"].values()
    assert seq["gps_input_count"] > 0 and seq["length_km"] < 1.0  # part of the ~1.2 km drive
    assert (run / "trajectory.png").stat().st_size > 10_000


def test_ctrl_c_in_sim_writes_what_was_played_and_exits_130(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """`taco-mav sim` interrupted while playing: the scoring of what was played is written, exit 130."""
    import taco_mav.sim.run as sim_run

    class Interrupted:
        def __init__(self, *a: object, **kw: object) -> None:
            self.stopped = False

        def start(self) -> None:
            pass

        def join(self, timeout: float | None = None) -> bool:
            if not self.stopped:
                raise KeyboardInterrupt
            return True

        def stop(self) -> None:
            self.stopped = True

        def results(self) -> dict:
            return {"sequences": {"d": {"ate_m": 0.5, "gps_input_count": 12}}, "summary": {}, "config": {}}

    monkeypatch.setattr(sim_run, "Simulator", Interrupted)
    (tmp_path / "drive").mkdir()
    rc = cli.main(["sim", "-q", "--drive", str(tmp_path / "drive"), "--connect", "udpout:127.0.0.1:9", "--out",
                   str(tmp_path / "s")])
    assert rc == 130 and capsys.readouterr().err.strip().splitlines()[-1] == "taco-mav sim: interrupted"
    assert json.loads((tmp_path / "s" / "results.json").read_text())["sequences"]["d"]["gps_input_count"] == 12


# ---------------------------------------------------------------- labels


def test_tables_and_plots_name_the_estimator_and_matcher(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib.axes

    from taco_mav.evaluation.plots import plot_run
    from taco_mav.evaluation.runner import DriveRun
    from taco_mav.evaluation.summary import made_by, table_md

    label = made_by("taco+", "classical")
    assert label == "estimator taco+, matcher classical"
    per_seq = {"05": {"ate_m": 1.0, "ate_imu_only_m": 9.0, "ate_m_per_km": 0.5, "steady_rmse_m": 0.8,
                      "fixes_per_km": 20.0, "ate_smoothed_m": 0.9, "attempts": 3, "accepted": 2,
                      "camera_duty_cycle": 0.1, "max_error_m": 2.0, "length_km": 2.0}}
    lines = table_md(per_seq, label).splitlines()
    assert lines[0] == "TACO, estimator taco+, matcher classical" and lines[2].startswith("| System | 05 |")
    titles: list[str] = []
    original = matplotlib.axes.Axes.set_title
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title",
                        lambda self, text, *a, **kw: (titles.append(text), original(self, text, *a, **kw))[1])
    n = 50
    xy = np.c_[np.linspace(0, 100, n), np.zeros(n)]
    run = DriveRun(name="d", sequence="05", t=np.arange(n) * 0.1, truth_xy=xy, truth_theta=np.zeros(n),
                   online_xy=xy + 0.5, online_theta=np.zeros(n), online_var=np.ones((n, 3)), imu_only_xy=xy + 2,
                   smoothed=None, queries=[], outcomes=[], frames_available=n, matcher_s=0.0, wall_s=0.0,
                   origin_utm=np.zeros(2), utm_epsg=32632)
    err = {"online": np.full(n, 0.5), "imu_only": np.full(n, 2.0)}
    paths = plot_run(run, err, tmp_path, label)
    assert [p.name for p in paths] == ["trajectory.png", "error_vs_distance.png", "error_cdf.png"]
    assert len(titles) == 3 and all(t.startswith("05: ") and t.endswith(f"({label})") for t in titles), titles
