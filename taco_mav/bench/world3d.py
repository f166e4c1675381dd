"""Bench: the 3-D synthetic world (`--realism 3d`): build time and camera frames per second.

A 0.3 km world (seed 3) is built in a temporary folder (`world3d_build_s`); then 60 consecutive 10 Hz frames
of its drive are rendered at the daemon's camera size (KITTI image_02, 1242 x 375) with moving cars, after one
warm-up frame: `world3d_frame_ms_p50` / `_p90` (wall), `world3d_fps` (1000 / p50) and `world3d_frame_cpu_ms`
(process CPU time per frame: llvmpipe's threads included, so it does not depend on other load). The OpenGL
renderer in use (llvmpipe on a machine without a GPU) is logged. The camera's speed
(taco+'s `cvgl.ground_motion.GroundMotion`, as the daemon's motion worker runs it every 0.5 s) is timed on
pairs of those frames 0.3 s apart: `ground_motion_ms_p50` / `_p90` (wall, one thread).
"""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

log = logging.getLogger(__name__)

N_FRAMES = 60


def run(progress: bool = False) -> dict[str, float]:
    from taco_mav.cvgl.ground_motion import GroundMotion
    from taco_mav.datasets.synthetic import build_world, load_world
    from taco_mav.datasets.synthetic.render3d import gl_info

    log.info("world3d: OpenGL renderer %s", gl_info()["renderer"])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        world = build_world(Path(tmp) / "w", seed=3, length_km=0.3, progress=False, realism="3d")
        build_s = time.perf_counter() - t0
        drive = load_world(world)
        renderer = drive.renderer()
        try:
            drive.frame(0)
            wall, frames, cpu0 = [], [], time.process_time()
            for i in tqdm(range(1, N_FRAMES + 1), desc="world3d frames", disable=not progress, leave=False):
                s = time.perf_counter()
                frames.append(drive.frame(i))
                wall.append(time.perf_counter() - s)
            cpu = (time.process_time() - cpu0) / N_FRAMES
        finally:
            renderer.close()
        gm = GroundMotion(drive.camera)
        motion = []
        for a in range(0, N_FRAMES - 3, 3):
            s = time.perf_counter()
            gm.measure(frames[a], frames[a + 3])
            motion.append(time.perf_counter() - s)
    p50 = float(np.percentile(wall, 50)) * 1e3
    return {"world3d_build_s": round(build_s, 2), "world3d_frame_ms_p50": round(p50, 1),
            "world3d_frame_ms_p90": round(float(np.percentile(wall, 90)) * 1e3, 1),
            "world3d_fps": round(1000.0 / p50, 2), "world3d_frame_cpu_ms": round(cpu * 1e3, 1),
            "ground_motion_ms_p50": round(float(np.percentile(motion, 50)) * 1e3, 1),
            "ground_motion_ms_p90": round(float(np.percentile(motion, 90)) * 1e3, 1)}
