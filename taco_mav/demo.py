"""`taco-mav demo`: the whole live path in one command, on loopback.

A small built-in synthetic world (fixed seed, ~1 km; reused when already in the out folder) is played by the
simulated ArduPilot rover (`taco_mav.sim.Simulator`) to the real daemon (`taco_mav.daemon.daemon.Daemon`, classical
matcher on frames rendered at the SIMSTATE pose), both as threads of this process talking MAVLink over UDP on
127.0.0.1, in lockstep at 8x real time (the daemon runs on the simulator's clock). GNSS is denied after the
start-up fix. The daemon's profile follows the estimator (`DEMO_PROFILES`): taco+ runs `synthetic_rover` (the
ardupilot_rover profile with the world's camera: what a rover runs), paper runs `synthetic` (the paper's numbers
with the world's camera). The world lives in `out/world` (shared by every run); each run writes into
`out/<estimator>-<matcher>` (e.g. `taco_demo/taco+-classical`, `taco_demo/paper-classical`): `results.json` (the
simulator's scoring), `trajectory.png` (truth vs the GPS_INPUT positions over the mosaic, titled with the
estimator, matcher and profile) and the daemon's logs (`daemon/`). A run folder that already holds results is
refused unless `force`. Ctrl-C stops the drive; what was played is still scored and written
(`DemoResult.interrupted`).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from taco_mav.checks import fresh_folder, number, output_dir
from taco_mav.checks import world as check_world
from taco_mav.errors import TacoError, UsageError

log = logging.getLogger(__name__)

__all__ = ["DEMO_ESTIMATOR", "DEMO_SEED", "DEMO_LENGTH_KM", "DEMO_SPEED", "DEMO_PROFILES", "DemoResult", "demo_profile",
           "demo_run_dir", "demo_title", "play_on_loopback", "run_demo"]

DEMO_SEED = 7
DEMO_LENGTH_KM = 1.0
DEMO_SPEED = 8.0
DEMO_ESTIMATOR = "taco+"  # what every rover profile runs
# The daemon's profile per estimator: taco+ as a rover runs it (ardupilot_rover's settings, the world's camera);
# paper mode as the paper states it (its defaults, the world's camera), which EKF3 refuses (docs/results.md).
DEMO_PROFILES = {"taco+": "synthetic_rover", "paper": "synthetic"}
RUN_FILES = ("results.json", "trajectory.png")  # with daemon/: what a run writes, removed first with force


@dataclass(frozen=True)
class DemoResult:
    """results: the drive's results.json entry; paths of the files written; wall_s: run time in seconds; daemon:
    the daemon's summary; estimator, matcher and profile (its name): what ran."""

    drive: str
    results: dict[str, Any]
    results_path: Path
    plot_path: Path
    world_dir: Path
    wall_s: float
    daemon: dict[str, Any]
    estimator: str = DEMO_ESTIMATOR
    matcher: str = "classical"
    profile: str = DEMO_PROFILES[DEMO_ESTIMATOR]
    interrupted: bool = False


def demo_world(out: Path, progress: bool = True) -> Path:
    """The demo world in `out/world`: reused when its world.json says it is ours, generated otherwise."""
    from taco_mav.datasets.synthetic import build_world

    world = Path(out) / "world"
    meta_path = world / "world.json"
    if meta_path.is_file():
        try:
            if json.loads(meta_path.read_text()).get("seed") == DEMO_SEED:
                check_world(world, "--out")  # a world cut short (Ctrl-C, a full disk) is made again
                log.info("reusing the demo world in %s", world)
                return world
        except (TacoError, OSError, ValueError, AttributeError) as exc:
            log.warning("%s is not a complete demo world (%s): generating it again", world, exc)
        else:
            log.info("%s is not the demo world: generating it again", world)
    log.info("generating the demo world (seed %d, ~%.1f km) in %s", DEMO_SEED, DEMO_LENGTH_KM, world)
    return build_world(world, seed=DEMO_SEED, length_km=DEMO_LENGTH_KM, progress=progress)


def demo_profile(estimator: str) -> str:
    """The name of the profile the demo's daemon runs with `estimator` ("taco+" or "paper")."""
    return DEMO_PROFILES[estimator]


def demo_title(estimator: str, matcher: str, profile: str, seq: dict[str, Any]) -> str:
    """The trajectory plot's title: which estimator, matcher and profile ran, and the drive's ATE (m) and length."""
    ate = seq["ate_m"] if seq.get("ate_m") is not None else float("nan")
    return (f"taco-mav demo ({estimator}, {matcher} matcher, profile {profile}): ATE {ate:.2f} m over "
            f"{seq['length_km']:.2f} km, GNSS denied after the start")


def demo_run_dir(out: Path, estimator: str, matcher: str) -> Path:
    """The folder a demo run writes into: named by what made it, `out/<estimator>-<matcher>`."""
    return Path(out) / f"{estimator}-{matcher}"


def _prepare(out: Path, speed: float, estimator: str, force: bool) -> tuple[Path, Any]:
    """Every check before the world is built: speed, estimator, out writable, run folder fresh (or cleared
    with force). Returns (run folder, profile)."""
    import shutil

    from taco_mav.config import Estimator, load_profile

    number(speed, "--speed", 0.0, 1000.0, low_open=True)
    try:
        Estimator(estimator)
    except ValueError:
        raise UsageError(f"--estimator {estimator}: unknown (known: {', '.join(e.value for e in Estimator)})") from None
    profile = load_profile(demo_profile(estimator))
    output_dir(out)
    run_dir = fresh_folder(demo_run_dir(out, estimator, profile.matcher), "results.json", force)
    if force:
        for name in RUN_FILES:
            (run_dir / name).unlink(missing_ok=True)
        shutil.rmtree(run_dir / "daemon", ignore_errors=True)
    return output_dir(run_dir), profile


def run_demo(out: Path, progress: bool = True, speed: float = DEMO_SPEED, duration_s: float | None = None,
             estimator: str = DEMO_ESTIMATOR, force: bool = False) -> DemoResult:
    """Run the demo into `out` (see the module docstring); returns what it measured and wrote."""
    out = Path(out)
    run_dir, profile = _prepare(out, speed, estimator, force)  # every check before the heavy imports
    from taco_mav.config import Estimator
    from taco_mav.datasets.synthetic import register_world_camera
    from taco_mav.sim import write_results
    from taco_mav.sim.plot import plot_gps_input

    register_world_camera()  # the daemon's camera is world:DIR
    world = demo_world(out, progress)
    start = time.monotonic()
    played = play_on_loopback(world, profile, Estimator(estimator), run_dir / "daemon", speed=speed,
                              duration_s=duration_s, progress=progress)
    sim, interrupted = played.sim, played.interrupted
    doc = sim.results()
    results_path = write_results(doc, run_dir)
    seq = doc["sequences"][sim.drive.name]
    plot_path = plot_gps_input(sim.drive, sim.monitor.updates, sim.play_start or 0.0, run_dir / "trajectory.png",
                               mosaic=sim.drive.world_dir / json.loads((world / "world.json").read_text())["mosaic"],
                               title=demo_title(estimator, profile.matcher, profile.name, seq))
    return DemoResult(drive=sim.drive.name, results=seq, results_path=results_path, plot_path=plot_path,
                      world_dir=world, wall_s=time.monotonic() - start, daemon=played.daemon,
                      estimator=estimator, matcher=profile.matcher, profile=profile.name, interrupted=interrupted)


@dataclass(frozen=True)
class LoopbackRun:
    """A drive played on loopback: the simulator (its results, drive and monitor), the daemon's summary, and
    whether Ctrl-C cut it short."""

    sim: Any
    daemon: dict[str, Any]
    interrupted: bool


def play_on_loopback(world: Path, profile: Any, estimator: Any, log_dir: Path, speed: float = DEMO_SPEED,
                     duration_s: float | None = None, progress: bool = True, seed: int = 0,
                     deny_after_s: float = 1.0) -> LoopbackRun:
    """The simulated autopilot (`Simulator`, lockstep at `speed` x real time, receiver noise seeded by `seed`,
    GNSS denied after `deny_after_s` drive seconds) playing `world`'s drive to the daemon (`profile`,
    `estimator`, camera world:WORLD, logs in `log_dir`), both threads of this process on a free UDP port of
    127.0.0.1. The `world:` camera scheme must be registered. Ctrl-C stops the drive (interrupted); a drive that
    gave no GPS_INPUT raises (KeyboardInterrupt again when interrupted, else TacoError)."""
    from taco_mav.daemon.daemon import Daemon, DaemonOptions
    from taco_mav.mavlink.connection import free_udp_port
    from taco_mav.sim import Simulator

    port = free_udp_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=speed, lockstep=True, duration_s=duration_s,
                    wait_companion_s=20.0, drain_s=0.3, seed=seed, deny_after_s=deny_after_s)
    daemon = Daemon(profile, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}",
                                           log_dir=log_dir, estimator=estimator),
                    clock=sim.clock, wall_clock=sim.utc_now)
    interrupted = False
    daemon.start()
    try:
        sim.start()
        _follow(sim, duration_s, progress)
    except KeyboardInterrupt:
        interrupted = True
        log.warning("interrupted: scoring what was played")
        sim.stop()
        sim.join(timeout=5.0)
    finally:
        daemon.stop()
        daemon.join(10.0)
    if sim.monitor.updates == []:
        if interrupted:
            raise KeyboardInterrupt
        if daemon.exit_code is None:
            raise TacoError("the daemon produced no GPS_INPUT (run with -v to see its log)")
    return LoopbackRun(sim, daemon.summary(), interrupted)


def _follow(sim: Any, duration_s: float | None, progress: bool) -> None:
    """Wait for the simulator to finish, with a bar of drive seconds played when `progress`."""
    bar = None
    if progress:
        from tqdm import tqdm

        total = sim.drive.duration_s if duration_s is None else min(duration_s, sim.drive.duration_s)
        bar = tqdm(total=round(total), desc="demo drive", unit="s")
    try:
        while not sim.join(timeout=0.5):
            if bar is not None and sim.play_start is not None:
                bar.n = min(bar.total, int(sim.clock.now() - sim.play_start))
                bar.refresh()
        if bar is not None:
            bar.n = bar.total
    finally:
        if bar is not None:
            bar.close()
