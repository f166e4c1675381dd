"""The command line's error contract (docs/cli.md), swept over every `taco-mav` command as real subprocesses: each
bad input exits with 1 (data/runtime) or 2 (usage/configuration) within 30 s, prints no traceback, at most 5 lines,
and the error line `taco-mav CMD: error: ...` names the offending option, file or value. Run 3 at a time (CI has 2
cores)."""

from __future__ import annotations

import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

TIME_LIMIT_S = 30.0
MAX_LINES = 5


@dataclass(frozen=True)
class Case:
    """args: the command line after `taco-mav` ({T} is the scratch folder); code: the exit code expected;
    needles: strings the error line must contain ({T} expanded)."""

    args: str
    code: int
    needles: tuple[str, ...]


@dataclass(frozen=True)
class Outcome:
    rc: int
    out: str
    wall_s: float


def write_geotiff(path: Path, size: int = 1024) -> Path:
    """A small tiled, compressed 3-band GeoTIFF in UTM 32N (0.2 m/px), like a mosaic."""
    import rasterio
    from rasterio.transform import Affine

    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (3, size, size), dtype=np.uint8)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=3, dtype="uint8",
                       crs="EPSG:32632", transform=Affine(0.2, 0.0, 455_000.0, 0.0, -0.2, 5_429_000.0), tiled=True,
                       blockxsize=256, blockysize=256, compress="deflate") as ds:
        ds.write(img)
    return path


def scratch(root: Path) -> Path:
    """The inputs the sweep refers to: a regular file (a parent no folder can be made in), an empty folder, a
    complete and a truncated GeoTIFF, a text file posing as one, a garbage tlog, earlier results."""
    (root / "afile").write_text("not a folder\n")
    (root / "empty").mkdir()
    (root / "drive").mkdir()
    good = write_geotiff(root / "good.tif")
    data = good.read_bytes()
    (root / "trunc.tif").write_bytes(data[: len(data) // 2])
    (root / "notatif.tif").write_text("hello\n")
    (root / "garbage.tlog").write_bytes(np.random.default_rng(1).integers(0, 255, 4000, dtype=np.uint8).tobytes())
    (root / "done").mkdir()
    (root / "done" / "results.json").write_text("{}\n")
    (root / "demo" / "taco+-classical").mkdir(parents=True)  # the default demo's run folder
    (root / "demo" / "taco+-classical" / "results.json").write_text("{}\n")
    (root / "worlddone").mkdir()
    (root / "worlddone" / "world.json").write_text("{}\n")
    (root / "cutworld").mkdir()  # a world whose mosaic download or generation was cut short
    (root / "cutworld" / "world.json").write_text('{"mosaic": "mosaic.tif"}\n')
    (root / "cutworld" / "mosaic.tif").write_bytes(data[: len(data) // 3])
    return root


RUN = "run --profile synthetic --connect udpin:127.0.0.1:9"
SIM = "sim --drive {T}/drive --connect udpout:127.0.0.1:9"
CASES: dict[str, Case] = {
    # bench
    "bench_only_unknown": Case("bench --out {T}/b.json --only fusoin", 2, ("--only fusoin", "unknown", "fusion")),
    "bench_only_empty": Case("bench --out {T}/b.json --only ,", 2, ("--only",)),
    "bench_out_unwritable": Case("bench --out {T}/afile/b.json --only fusion", 2, ("--out", "{T}/afile/b.json")),
    "bench_out_folder": Case("bench --out {T}/empty", 2, ("--out {T}/empty", "is a folder")),
    # world
    "world_out_unwritable": Case("world --out {T}/afile/w", 2, ("--out {T}/afile/w", "cannot create")),
    "world_out_exists": Case("world --out {T}/worlddone", 2, ("--out {T}/worlddone", "world.json", "--force")),
    "world_length_zero": Case("world --out {T}/w --length-km 0", 2, ("--length-km 0",)),
    "world_centre_range": Case("world --out {T}/w --centre -95.1,149.2", 2, ("--centre -95.1,149.2", "latitude")),
    "world_centre_text": Case("world --out {T}/w --centre karlsruhe", 2, ("--centre karlsruhe", "LAT,LON")),
    "world_imu_unknown": Case("world --out {T}/w --imu mems", 2, ("--imu", "mems")),
    "world_along_missing": Case("world --out {T}/w --along-drive {T}/nodrive", 2, ("--along-drive {T}/nodrive",)),
    # eval
    "eval_out_unwritable": Case("eval --drive {T}/drive --out {T}/afile/e", 2, ("--out {T}/afile/e",)),
    "eval_out_has_results": Case("eval --drive {T}/drive --out {T}/done", 2, ("--out {T}/done", "--force")),
    "eval_drive_missing": Case("eval --drive {T}/nodrive --out {T}/e", 2, ("--drive {T}/nodrive", "no such")),
    "eval_drive_malformed": Case("eval --drive {T}/drive --out {T}/e1", 1, ("{T}/drive",)),
    "eval_world_mosaic_truncated": Case("eval --drive {T}/cutworld --out {T}/e", 1, ("{T}/cutworld/mosaic.tif",
                                                                                      "truncated")),
    "eval_sequence_unknown": Case("eval --kitti-root {T}/empty --sequences 99 --out {T}/e", 2, ("--sequences 99",)),
    "eval_sequences_no_root": Case("eval --sequences 05 --out {T}/e", 2, ("--kitti-root",)),
    "eval_ablation_unknown": Case("eval --drive {T}/drive --ablation no_gate --out {T}/e", 2,
                                  ("no_gate", "no_yaw_gate")),
    "eval_ablations_unknown": Case("eval --drive {T}/drive --ablations full,foo --out {T}/e", 2, ("--ablations foo",)),
    "eval_matcher_unknown": Case("eval --drive {T}/drive --matcher sift --out {T}/e", 2, ("--matcher", "sift")),
    "eval_estimator_unknown": Case("eval --drive {T}/drive --estimator ekf --out {T}/e", 2, ("--estimator", "ekf")),
    "eval_profile_missing": Case("eval --profile nosuch --drive {T}/drive --out {T}/e", 2, ("nosuch",)),
    "eval_latency_negative": Case("eval --drive {T}/drive --matcher-latency -1 --out {T}/e", 2,
                                  ("--matcher-latency -1",)),
    "eval_nothing": Case("eval --out {T}/e", 2, ("nothing to evaluate",)),
    "eval_tlog_without_frames": Case("eval --tlog {T}/garbage.tlog --out {T}/e", 2,
                                     ("--tlog SESSION/mav.tlog --frames SESSION/frames --map",)),
    "eval_map_alone": Case("eval --drive {T}/drive --map {T}/good.tif --out {T}/e", 2, ("--map goes with --tlog",)),
    "eval_tlog_missing": Case("eval --tlog {T}/no.tlog --frames {T} --map {T}/good.tif --out {T}/e", 2,
                              ("--tlog {T}/no.tlog", "no such file")),
    "eval_option_typo": Case("eval --drive {T}/drive --ouput {T}/e", 2, ("--ouput",)),
    # drift
    "drift_tlog_missing": Case("drift --tlog {T}/no.tlog", 2, ("--tlog {T}/no.tlog", "no such file")),
    "drift_tlog_garbage": Case("drift --tlog {T}/garbage.tlog", 1, ("{T}/garbage.tlog",)),
    "drift_out_unwritable": Case("drift --tlog {T}/garbage.tlog --out {T}/afile/d.json", 2,
                                 ("--out {T}/afile/d.json",)),
    "drift_min_speed": Case("drift --tlog {T}/garbage.tlog --min-speed -1", 2, ("--min-speed -1",)),
    # run (the daemon)
    "run_no_camera": Case(RUN, 2, ("--camera", "--dead-reckoning")),
    "run_no_map": Case(f"{RUN} --camera 0", 2, ("--map", "--camera 0")),
    "run_map_missing": Case(f"{RUN} --camera 0 --map {{T}}/no.tif", 2, ("--map {T}/no.tif", "no such file")),
    "run_map_truncated": Case(f"{RUN} --camera 0 --map {{T}}/trunc.tif", 1, ("--map {T}/trunc.tif", "truncated")),
    "run_map_not_tiff": Case(f"{RUN} --camera 0 --map {{T}}/notatif.tif", 1, ("--map {T}/notatif.tif", "GeoTIFF")),
    "run_world_missing": Case(f"{RUN} --camera world:{{T}}/noworld", 2, ("{T}/noworld", "world.json")),
    "run_world_mosaic_truncated": Case(f"{RUN} --camera world:{{T}}/cutworld", 1,
                                       ("{T}/cutworld/mosaic.tif", "truncated")),
    "run_camera_folder_missing": Case(f"{RUN} --camera folder:{{T}}/nopics --map {{T}}/good.tif", 2, ("{T}/nopics",)),
    "run_profile_missing": Case("run --profile nosuch --connect udpin:127.0.0.1:9 --dead-reckoning", 2, ("nosuch",)),
    "run_connect_typo": Case("run --profile synthetic --connect udpn:127.0.0.1:9 --dead-reckoning", 2,
                             ("--connect udpn:127.0.0.1:9",)),
    "run_connect_no_port": Case("run --profile synthetic --connect udpin:127.0.0.1 --dead-reckoning", 2,
                                ("--connect", "udpin:127.0.0.1")),
    "run_camera_device_missing": Case(f"{RUN} --camera 7 --map {{T}}/good.tif", 2, ("--camera '7'", "cannot open")),
    "run_serial_missing": Case("run --profile synthetic --connect /dev/ttyNOPE:57600 --dead-reckoning", 1,
                               ("--connect", "/dev/ttyNOPE")),
    "run_origin_bad": Case(f"{RUN} --dead-reckoning --origin 1,2,3,4", 2, ("--origin 1,2,3,4",)),
    "run_log_dir_unwritable": Case(f"{RUN} --dead-reckoning --log-dir {{T}}/afile/logs", 2,
                                   ("--log-dir {T}/afile/logs",)),
    "run_signing_key_missing": Case(f"{RUN} --dead-reckoning --signing-key {{T}}/no.key", 2, ("{T}/no.key",)),
    "run_estimator_unknown": Case(f"{RUN} --dead-reckoning --estimator ekf", 2, ("--estimator", "ekf")),
    # sim
    "sim_drive_missing": Case("sim --drive {T}/nodrive --connect udpout:127.0.0.1:9 --out {T}/s", 2,
                              ("--drive {T}/nodrive",)),
    "sim_speed_zero": Case(f"{SIM} --out {{T}}/s --speed 0", 2, ("--speed 0",)),
    "sim_speed_negative": Case(f"{SIM} --out {{T}}/s --speed -2", 2, ("--speed -2",)),
    "sim_home_short": Case(f"{SIM} --out {{T}}/s --home 49.0,8.4", 2, ("--home 49.0,8.4", "LAT,LON,ALT")),
    "sim_out_unwritable": Case(f"{SIM} --out {{T}}/afile/s", 2, ("--out {T}/afile/s",)),
    "sim_out_has_results": Case(f"{SIM} --out {{T}}/done", 2, ("--out {T}/done", "--force")),
    "sim_spoof_drift_alone": Case(f"{SIM} --out {{T}}/s --spoof-drift 1", 2, ("--spoof-drift",)),
    # calibrate
    "calibrate_images_missing": Case("calibrate --images {T}/nopics --out {T}/c.yaml", 2, ("--images {T}/nopics",)),
    "calibrate_images_empty": Case("calibrate --images {T}/empty --out {T}/c.yaml", 1,
                                   ("--images {T}/empty", "no images")),
    "calibrate_board_bad": Case("calibrate --images {T}/empty --board 9by6 --out {T}/c.yaml", 2, ("--board", "9by6")),
    "calibrate_square_zero": Case("calibrate --images {T}/empty --square 0 --out {T}/c.yaml", 2, ("--square 0",)),
    "calibrate_out_unwritable": Case("calibrate --images {T}/empty --out {T}/afile/c.yaml", 2,
                                     ("--out {T}/afile/c.yaml",)),
    # demo
    "demo_speed_zero": Case("demo --out {T}/d --speed 0", 2, ("--speed 0",)),
    "demo_out_unwritable": Case("demo --out {T}/afile/d", 2, ("--out {T}/afile/d",)),
    "demo_run_exists": Case("demo --out {T}/demo", 2, ("{T}/demo/taco+-classical", "--force")),
    "demo_estimator_unknown": Case("demo --out {T}/d --estimator ekf", 2, ("--estimator", "ekf")),
    # mission
    "mission_binary_missing": Case("mission --autopilot ardupilot --ardurover {T}/nobin --out {T}/m.json", 2,
                                   ("--ardurover {T}/nobin", "no such file")),
    "mission_option_of_px4": Case("mission --autopilot ardupilot --gcs-origin --out {T}/m.json", 2,
                                  ("--[no-]gcs-origin", "px4 only")),
    "mission_autopilot_unknown": Case("mission --autopilot betaflight --out {T}/m.json", 2, ("--autopilot",)),
    # the command itself
    "command_unknown": Case("calibrat --images x", 2, ("calibrat",)),
    "command_missing": Case("", 2, ("COMMAND",)),
    "global_flag_typo": Case("--quiett demo", 2, ("--quiett",)),
}


def _run(args: list[str]) -> Outcome:
    start = time.monotonic()
    try:
        proc = subprocess.run([sys.executable, "-m", "taco_mav.cli", *args], capture_output=True, text=True,
                              timeout=TIME_LIMIT_S * 2)
    except subprocess.TimeoutExpired as exc:
        return Outcome(-9, f"{exc.stdout or ''}{exc.stderr or ''}", time.monotonic() - start)
    return Outcome(proc.returncode, proc.stdout + proc.stderr, time.monotonic() - start)


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Outcome, Path]]:
    """Every case run once, three subprocesses at a time."""
    root = scratch(tmp_path_factory.mktemp("bad_inputs"))
    with ThreadPoolExecutor(max_workers=3) as pool:
        futures = {name: pool.submit(_run, case.args.replace("{T}", str(root)).split())
                   for name, case in CASES.items()}
        return {name: (f.result(), root) for name, f in futures.items()}


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_one_clean_line(outcomes: dict[str, tuple[Outcome, Path]], name: str) -> None:
    case = CASES[name]
    res, root = outcomes[name]
    lines = res.out.strip().splitlines()
    assert res.rc == case.code, res.out
    assert res.wall_s < TIME_LIMIT_S, f"{res.wall_s:.1f} s"
    assert "Traceback" not in res.out
    assert 1 <= len(lines) <= MAX_LINES, res.out
    errors = [ln for ln in lines if ": error: " in ln]
    assert len(errors) == 1, res.out
    command = case.args.split()[0] if case.args and not case.args.startswith("-") else ""
    if command in ("bench", "world", "eval", "drift", "run", "sim", "calibrate", "demo", "mission"):
        assert errors[0].startswith(f"taco-mav {command}: error: "), errors[0]
    for needle in case.needles:
        assert needle.replace("{T}", str(root)) in errors[0], errors[0]


def test_nothing_was_written_by_refused_commands(outcomes: dict[str, tuple[Outcome, Path]]) -> None:
    """Refused before work: no output folder or file appears for a usage error."""
    _, root = next(iter(outcomes.values()))
    for name in ("w", "e", "s", "d", "b.json", "c.yaml", "m.json", "m"):
        assert not (root / name).exists(), name
    assert (root / "done" / "results.json").read_text() == "{}\n"  # an earlier run's results are kept
    assert sorted(p.name for p in (root / "demo").iterdir()) == ["taco+-classical"]


def test_debug_shows_the_traceback(tmp_path: Path) -> None:
    """--debug (before or after the command) adds the traceback; the error line and exit code stay."""
    for args in (["--debug", "bench", "--out", str(tmp_path / "b.json"), "--only", "nope"],
                 ["bench", "--out", str(tmp_path / "b.json"), "--only", "nope", "--debug"]):
        res = _run(args)
        assert res.rc == 2 and "Traceback" in res.out, res.out
        assert res.out.strip().splitlines()[-1].startswith("taco-mav bench: error: --only nope")
