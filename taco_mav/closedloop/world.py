"""The synthetic world the daemon's camera sees in a closed-loop mission, centred on the autopilot's home
(`taco-mav world`, run as a user runs it)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from taco_mav.closedloop.geometry import square_corners


def mission_world(out: Path, spec: Any) -> Path:
    """OUT/world, centred on `spec.home` (kept when it is there already, of `spec.realism`). `spec`: an
    `ardupilot.MissionSpec` or a `px4.Px4MissionSpec` (world_seed, home, side_m, realism, keep_clear). A 3-D world
    keeps its buildings, trees, poles and parked cars off the mission's square (`taco-mav world --keep-clear`), as
    it keeps them off its own drive: SITL has no obstacles, and a real rover would not drive through a house."""
    world = out / "world"
    meta = world / "world.json"
    if meta.exists() and json.loads(meta.read_text()).get("realism", "flat") == spec.realism and spec.keep_clear:
        return world
    cmd = [sys.executable, "-m", "taco_mav.cli", "world", "-q", "--out", str(world), "--seed", str(spec.world_seed),
           "--length-km", "0.6", f"--centre={spec.home[0]},{spec.home[1]}", "--realism", spec.realism, "--force"]
    if spec.realism == "3d" and spec.keep_clear:
        square = [(0.0, 0.0)] + square_corners(spec.side_m)
        cmd.append("--keep-clear=" + ";".join(f"{e:g},{n:g}" for e, n in square))
    subprocess.run(cmd, check=True)
    return world
