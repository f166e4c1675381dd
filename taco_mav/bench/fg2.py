"""Bench section `fg2`: the published FG2 model through `Fg2Matcher`, five crops per trigger.

`taco-mav bench --only fg2 --fg2-checkout DIR [--fg2-checkpoint F] --device cuda|cpu` runs it; without a
checkout the section is skipped and its keys are absent. Without a checkpoint the model has random weights
(`cvgl/fg2/shim.py build_random_model`, seeded): timing and memory do not depend on the weights.

Keys:
- `fg2_trigger_ms_p50`, `fg2_trigger_ms_p90`: wall time of `Fg2Matcher.match` on one ground frame (KITTI camera,
  1242 x 375) and five 512 px crops at 0.2 m/px, from uint8 arrays to MatchResults (CUDA synchronised), over
  `triggers` triggers after `warmup` untimed ones;
- `fg2_crop_ms`: median time per crop, trigger time / 5 (what MatchResult.elapsed_s reports);
- `fg2_cut_ms_p50`, `fg2_cut_ms_p90`: wall time to cut the five heading-up crops of a trigger (heading 0.3 rad,
  centres 10 m apart) from a synthetic in-memory mosaic (2048 px square, 0.2 m/px, written to a temporary
  folder), by the path in use, `fg2_crop_path`: "cpu" (five `SatelliteMap.crop`, cv2 on the CPU; the matcher
  then uploads uint8 crops inside the trigger) or "device" (`--fg2-device-crops`, fg2.device_crops: one
  `Fg2Matcher.cut_crops`, resampled on the matcher's device, CUDA synchronised; the trigger then starts from
  them). Cut + trigger is a whole trigger either way;
- `fg2_peak_gb`: on CUDA, torch.cuda.max_memory_allocated over model build and all triggers (weights included),
  GiB; on a CPU, the growth of the process's peak resident memory (ru_maxrss) from before the model was built
  (weights and the build's transient copies included), GiB; `fg2_peak_source` says which.
Also `fg2_device`, `fg2_triggers`, `fg2_fast`, `fg2_compile`, `fg2_random_weights`.
"""

from __future__ import annotations

import logging
import math
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

CROPS = 5
CROP_PX = 512
CROP_M_PER_PX = 0.2
GIB = 1024.0 ** 3
HEADING = 0.3  # rad: not axis-aligned
MOSAIC_PX = 2048  # 410 m square at CROP_M_PER_PX: five 512 px crops 10 m apart fit at any heading
OFFSETS_M = np.array([[-10.0, 0.0], [0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [0.0, -10.0]])  # (forward, left)


def _write_mosaic(path: Path) -> Path:
    """A textured RGB GeoTIFF (2 m random blocks), UTM 32N, CROP_M_PER_PX m/px."""
    import rasterio

    rng = np.random.default_rng(0)
    img = np.repeat(np.repeat(rng.integers(0, 256, (3, MOSAIC_PX // 10, MOSAIC_PX // 10), dtype=np.uint8), 10, 1),
                    10, 2)
    img = np.ascontiguousarray(np.pad(img, ((0, 0), (0, MOSAIC_PX - img.shape[1]), (0, MOSAIC_PX - img.shape[2]))))
    transform = rasterio.Affine(CROP_M_PER_PX, 0.0, 456_000.0, 0.0, -CROP_M_PER_PX, 5_430_000.0)
    with rasterio.open(path, "w", driver="GTiff", width=MOSAIC_PX, height=MOSAIC_PX, count=3, dtype="uint8",
                       crs="EPSG:32632", transform=transform) as dst:
        dst.write(img)
    return path


def _centres(sat: Any) -> np.ndarray:
    """The five crop centres (absolute UTM E, N): back, centre, forward, left, right of the mosaic's centre."""
    e0, n0, e1, n1 = sat.bounds_utm
    c, s = math.cos(HEADING), math.sin(HEADING)
    fwd, left = OFFSETS_M[:, 0], OFFSETS_M[:, 1]
    return np.c_[(e0 + e1) / 2 + fwd * c - left * s, (n0 + n1) / 2 + fwd * s + left * c]


def _rss_bytes() -> int:
    """Current resident set size of this process (Linux /proc), bytes."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


def run(progress: bool = True, checkout: str | None = None, checkpoint: str | None = None, device: str = "cuda",
        triggers: int | None = None, warmup: int | None = None, fast: bool = True,
        compile: bool = False, device_crops: bool = False) -> dict[str, Any]:
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
    from taco_mav.camera.geometry import GroundCamera
    from taco_mav.config import CameraConfig, Fg2Config
    from taco_mav.cvgl.base import GroundFrame
    from taco_mav.cvgl.fg2.adapter import Fg2Matcher, resolve_device
    from taco_mav.cvgl.fg2.shim import build_random_model
    from taco_mav.cvgl.satellite import SatelliteMap

    cfg = Fg2Config(checkout=str(checkout), checkpoint=str(checkpoint or ""), device=device, fast=fast,
                    compile=compile, device_crops=device_crops)
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
    times, cut_times = [], []
    with tempfile.TemporaryDirectory() as tmp, SatelliteMap(_write_mosaic(Path(tmp) / "mosaic.tif")) as sat:
        centres = _centres(sat)
        for i in range(warmup + triggers):
            start = time.perf_counter()
            if device_crops:
                batch = matcher.cut_crops(sat, centres, HEADING, CROP_PX, CROP_M_PER_PX)
                if cuda:
                    torch.cuda.synchronize(dev)
            else:
                crops = [sat.crop(c, HEADING, CROP_PX, CROP_M_PER_PX) for c in centres]
            cut = time.perf_counter()
            if device_crops:
                matcher.match_crops(frame, batch)  # synchronises CUDA before returning
            else:
                matcher.match(frame, crops)
            end = time.perf_counter()
            if i >= warmup:
                times.append((end - cut) * 1000.0)
                cut_times.append((cut - start) * 1000.0)
            if progress:
                log.info("bench fg2: trigger %d/%d: crops %.1f ms, matcher %.1f ms%s", i + 1, warmup + triggers,
                         (cut - start) * 1000.0, (end - cut) * 1000.0, " (warm-up)" if i < warmup else "")
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
            "fg2_random_weights": not checkpoint,
            "fg2_cut_ms_p50": round(float(np.percentile(cut_times, 50)), 2),
            "fg2_cut_ms_p90": round(float(np.percentile(cut_times, 90)), 2),
            "fg2_crop_path": "device" if device_crops else "cpu"}
