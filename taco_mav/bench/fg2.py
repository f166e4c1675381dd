"""Bench section `fg2`: the published FG2 model through `Fg2Matcher`, five crops per trigger.

`taco-mav bench --only fg2 --fg2-checkout DIR [--fg2-checkpoint F] --device cuda|cpu` runs it; without a
checkout the section is skipped and its keys are absent. Without a checkpoint the model has random weights
(`fg2_shim.build_random_model`, seeded): timing and memory do not depend on the weights.

Keys:
- `fg2_trigger_ms_p50`, `fg2_trigger_ms_p90`: wall time of `Fg2Matcher.match` on one ground frame (KITTI camera,
  1242 x 375) and five 512 px crops at 0.2 m/px, from uint8 arrays to MatchResults (CUDA synchronised), over
  `triggers` triggers after `warmup` untimed ones;
- `fg2_crop_ms`: median time per crop, trigger time / 5 (what MatchResult.elapsed_s reports);
- `fg2_peak_gb`: on CUDA, torch.cuda.max_memory_allocated over model build and all triggers (weights included),
  GiB; on a CPU, the growth of the process's peak resident memory (ru_maxrss) from before the model was built
  (weights and the build's transient copies included), GiB; `fg2_peak_source` says which.
Also `fg2_device`, `fg2_triggers`, `fg2_fast`, `fg2_compile`, `fg2_random_weights`.
"""

from __future__ import annotations

import logging
import resource
import time
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

CROPS = 5
CROP_PX = 512
CROP_M_PER_PX = 0.2
GIB = 1024.0 ** 3


def _rss_bytes() -> int:
    """Current resident set size of this process (Linux /proc), bytes."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def run(progress: bool = True, checkout: str | None = None, checkpoint: str | None = None, device: str = "cuda",
        triggers: int | None = None, warmup: int | None = None, fast: bool = True,
        compile: bool = False) -> dict[str, Any]:
    """The fg2 keys (empty without a checkout or without torch). triggers / warmup default to 20 / 3 on CUDA
    and 3 / 1 on a CPU (a CPU trigger of the full model takes minutes)."""
    if not checkout:
        log.info("bench fg2: no --fg2-checkout given; the fg2 keys are left out")
        return {}
    try:
        import torch
    except ImportError:
        log.warning("bench fg2: torch is not installed (pip install 'taco_mav[fg2]'); the fg2 keys are left out")
        return {}
    from taco_mav.camera_geometry import GroundCamera
    from taco_mav.config import CameraConfig, Fg2Config
    from taco_mav.cvgl.base import Crop, GroundFrame
    from taco_mav.cvgl.fg2 import Fg2Matcher, resolve_device
    from taco_mav.cvgl.fg2_shim import build_random_model

    cfg = Fg2Config(checkout=str(checkout), checkpoint=str(checkpoint or ""), device=device, fast=fast,
                    compile=compile)
    dev = resolve_device(device)
    cuda = dev.type == "cuda"
    triggers = triggers if triggers is not None else (20 if cuda else 3)
    warmup = warmup if warmup is not None else (3 if cuda else 1)
    if cuda:
        torch.cuda.reset_peak_memory_stats(dev)
    rss0 = _rss_bytes()
    model = None if checkpoint else build_random_model(Path(checkout), dev, seed=0)
    camera = GroundCamera.from_config(CameraConfig())
    matcher = Fg2Matcher(cfg, camera, model=model)
    rng = np.random.default_rng(0)
    frame = GroundFrame(rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8), 0.0, camera)
    crops = [Crop(rng.integers(0, 256, (CROP_PX, CROP_PX, 3), dtype=np.uint8), np.array([0.0, 10.0 * i]), 0.3,
                  CROP_M_PER_PX) for i in range(CROPS)]
    times = []
    for i in range(warmup + triggers):
        start = time.perf_counter()
        matcher.match(frame, crops)  # synchronises CUDA before returning
        elapsed = time.perf_counter() - start
        if i >= warmup:
            times.append(elapsed * 1000.0)
        if progress:
            log.info("bench fg2: trigger %d/%d %.1f ms%s", i + 1, warmup + triggers, elapsed * 1000.0,
                     " (warm-up)" if i < warmup else "")
    if cuda:
        peak, source = torch.cuda.max_memory_allocated(dev) / GIB, "cuda_max_memory_allocated"
    else:
        peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB
        peak, source = max(peak_rss - rss0, 0) / GIB, "cpu_rss_growth"
    t = np.asarray(times)
    return {"fg2_trigger_ms_p50": round(float(np.percentile(t, 50)), 2),
            "fg2_trigger_ms_p90": round(float(np.percentile(t, 90)), 2),
            "fg2_crop_ms": round(float(np.percentile(t, 50)) / CROPS, 2),
            "fg2_peak_gb": round(float(peak), 3), "fg2_peak_source": source, "fg2_device": str(dev),
            "fg2_triggers": len(times), "fg2_fast": bool(fast), "fg2_compile": bool(compile),
            "fg2_random_weights": not checkpoint}
