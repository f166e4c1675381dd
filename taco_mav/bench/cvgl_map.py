"""Bench: heading-up satellite crops per second (`map_crops_per_s`).

A ~2 x 2 km synthetic RGB GeoTIFF at 0.2 m/px (10 000 px square, UTM 32N) is written to a temporary folder;
512 x 512 crops at 0.2 m/px are cut at random centres (kept 80 m inside the edges) and headings, seed 0, on the
calling thread with OpenCV limited to one thread. `map_crops_per_s` is the in-memory rate after the first touch (the mosaic is read at open);
`map_open_s` is the time to open and decode the file, `map_crops_per_s_block_cache` the rate when the mosaic is
served from the 256 px block cache instead (cold start included).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import rasterio
from tqdm import tqdm

from taco_mav.cvgl.satellite import SatelliteMap

SIZE_PX, RES, CROP_PX, N_CROPS = 10_000, 0.2, 512, 2000


def _write_mosaic(path: Path, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, size=(3, SIZE_PX // 50, SIZE_PX // 50), dtype=np.uint8)
    img = np.repeat(np.repeat(small, 50, axis=1), 50, axis=2)  # 10 m texture blocks
    transform = rasterio.Affine(RES, 0.0, 456_000.0, 0.0, -RES, 5_430_000.0)
    with rasterio.open(path, "w", driver="GTiff", width=SIZE_PX, height=SIZE_PX, count=3, dtype="uint8",
                       crs="EPSG:32632", transform=transform, tiled=True, blockxsize=256, blockysize=256) as dst:
        dst.write(img)


def _rate(sat: SatelliteMap, n: int, seed: int, progress: bool) -> float:
    rng = np.random.default_rng(seed)
    e0, n0, e1, n1 = sat.bounds_utm
    centres = np.c_[rng.uniform(e0 + 80, e1 - 80, n), rng.uniform(n0 + 80, n1 - 80, n)]
    headings = rng.uniform(-np.pi, np.pi, n)
    start = time.perf_counter()
    for c, h in tqdm(zip(centres, headings), total=n, disable=not progress, desc="crops"):
        sat.crop(c, float(h), CROP_PX, RES)
    return n / (time.perf_counter() - start)


def run(progress: bool = False) -> dict[str, float]:
    """Crop rates in crops/s (OpenCV limited to one thread) and the open time in s."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        return _run(progress)
    finally:
        cv2.setNumThreads(threads)


def _run(progress: bool) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mosaic.tif"
        _write_mosaic(path)
        start = time.perf_counter()
        with SatelliteMap(path) as sat:
            open_s = time.perf_counter() - start
            rate = _rate(sat, N_CROPS, 0, progress)
        with SatelliteMap(path, in_memory_max_mb=0.0) as sat:
            rate_blocks = _rate(sat, N_CROPS // 4, 1, progress)
    return {"map_crops_per_s": rate, "map_open_s": open_s, "map_crops_per_s_block_cache": rate_blocks}
