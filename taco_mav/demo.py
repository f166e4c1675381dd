"""`taco-mav demo`: the whole live path in one command, on loopback.

A small built-in synthetic world (fixed seed, ~1 km; reused when already in the out folder) is played by the
simulated ArduPilot rover (`taco_mav.sim.Simulator`) to the real daemon (`taco_mav.link.daemon.Daemon`, profile
`synthetic`, classical matcher on frames rendered at the SIMSTATE pose), both as threads of this process talking
MAVLink over UDP on 127.0.0.1, in lockstep at 8x real time (the daemon runs on the simulator's clock). GNSS is
denied after the start-up fix. Writes `results.json` (the simulator's scoring), `trajectory.png` (truth vs the
GPS_INPUT positions over the mosaic) and the daemon's logs (`daemon/`) into `out`.
"""

from __future__ import annotations

import json
import logging
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from taco_mav.errors import TacoError

log = logging.getLogger(__name__)

__all__ = ["DEMO_SEED", "DEMO_LENGTH_KM", "DEMO_SPEED", "DemoResult", "run_demo"]

DEMO_SEED = 7
DEMO_LENGTH_KM = 1.0
DEMO_SPEED = 8.0


@dataclass(frozen=True)
class DemoResult:
    """results: the drive's results.json entry; paths of the files written; wall_s: run time in seconds."""

    drive: str
    results: dict[str, Any]
    results_path: Path
    plot_path: Path
    world_dir: Path
    wall_s: float
    daemon: dict[str, Any]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def demo_world(out: Path, progress: bool = True) -> Path:
    """The demo world in `out/world`: reused when its world.json says it is ours, generated otherwise."""
    from taco_mav.datasets.synthetic import build_world

    world = Path(out) / "world"
    meta_path = world / "world.json"
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
            if meta.get("seed") == DEMO_SEED and (world / meta["mosaic"]).is_file():
                log.info("reusing the demo world in %s", world)
                return world
        except (OSError, ValueError, KeyError):
            pass
        log.info("%s is not the demo world: generating it again", world)
    log.info("generating the demo world (seed %d, ~%.1f km) in %s", DEMO_SEED, DEMO_LENGTH_KM, world)
    return build_world(world, seed=DEMO_SEED, length_km=DEMO_LENGTH_KM, progress=progress)


def run_demo(out: Path, progress: bool = True, speed: float = DEMO_SPEED, duration_s: float | None = None,
             estimator: str = "paper") -> DemoResult:
    """Run the demo into `out` (see the module docstring); returns what it measured and wrote."""
    from taco_mav.config import Estimator, load_profile
    from taco_mav.link.daemon import Daemon, DaemonOptions
    from taco_mav.sim import Simulator, write_results
    from taco_mav.sim.plot import plot_gps_input

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    world = demo_world(out, progress)
    start = time.monotonic()
    port = _free_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=speed, lockstep=True, duration_s=duration_s,
                    wait_companion_s=20.0, drain_s=0.3)
    daemon = Daemon(load_profile("synthetic"),
                    DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}", log_dir=out / "daemon",
                                  estimator=Estimator(estimator)),
                    clock=sim.clock, wall_clock=sim.utc_now)
    daemon.start()
    try:
        sim.start()
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=round(sim.drive.duration_s if duration_s is None else min(duration_s, sim.drive.duration_s)),
                       desc="demo drive", unit="s")
        while not sim.join(timeout=0.5):
            if bar is not None and sim.play_start is not None:
                bar.n = min(bar.total, int(sim.clock.now() - sim.play_start))
                bar.refresh()
        if bar is not None:
            bar.n = bar.total
            bar.close()
    except KeyboardInterrupt:
        sim.stop()
        sim.join(timeout=5.0)
    finally:
        daemon.stop()
        daemon.join(10.0)
    if daemon.exit_code is None and sim.monitor.updates == []:
        raise TacoError("the daemon produced no GPS_INPUT (see the log above)")
    doc = sim.results()
    results_path = write_results(doc, out)
    seq = doc["sequences"][sim.drive.name]
    plot_path = plot_gps_input(sim.drive, sim.monitor.updates, sim.play_start or 0.0, out / "trajectory.png",
                               mosaic=sim.drive.world_dir / json.loads((world / "world.json").read_text())["mosaic"],
                               title=f"taco-mav demo: ATE {seq['ate_m'] or float('nan'):.2f} m over "
                                     f"{seq['length_km']:.2f} km, GNSS denied after the start")
    return DemoResult(drive=sim.drive.name, results=seq, results_path=results_path, plot_path=plot_path,
                      world_dir=world, wall_s=time.monotonic() - start, daemon=daemon.summary())
