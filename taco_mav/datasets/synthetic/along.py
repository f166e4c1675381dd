"""A synthetic world around a real KITTI drive: the roads follow its GPS track, its real OXTS is replayed.

The driven track (UTM, from the KITTI reader) is smoothed and becomes the centreline of a two-lane road
shifted 1.75 m to the left of the track (the car keeps to the right-hand lane); side streets branch off it
every 60-140 m; buildings, lots and trees are placed around them as in the grid world. The drive written is
the real one: its OXTS packets and timestamps copied into the world's KITTI layout under the real drive name,
and its truth is the OXTS position (UTM) with the grid heading (OXTS yaw + meridian convergence).
Local frame: ENU metres relative to the drive's first fix.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter1d
from tqdm import tqdm

from taco_mav.config import CameraConfig
from taco_mav.datasets.kitti import OXTS, load_drive
from taco_mav.datasets.synthetic import kitti_writer as kw
from taco_mav.datasets.synthetic.layout import layout_scene
from taco_mav.datasets.synthetic.roads import Road, resample_polyline
from taco_mav.datasets.synthetic.world_base import GENERATOR_VERSION, M_PER_PX, paint_and_write, world_extent
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["build_along_world", "roads_along"]


def roads_along(track: np.ndarray, rng: np.random.Generator, width_m: float = 7.5) -> tuple[list[Road], np.ndarray, np.ndarray]:
    """Roads for a driven track (N, 2) local metres: the main road (split at each side-street junction) and
    side streets; returns (roads, junctions (K, 2), junction styles (K,))."""
    line = resample_polyline(track, 1.0)
    if len(line) < 10:
        raise DataError(f"--along-drive: the drive covers only {len(line)} m, too short for a world")
    line = gaussian_filter1d(line, 3.0, axis=0, mode="nearest")
    d = np.gradient(line, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    left = np.c_[-d[:, 1], d[:, 0]]
    centre = line + left * (width_m / 4.0)
    cuts, side, junctions = [], [], []
    i = int(rng.uniform(40, 100))
    while i < len(centre) - 40:
        sides = [s for s in (-1.0, 1.0) if rng.random() < 0.6]
        if sides:
            cuts.append(i)
            junctions.append(centre[i])
            for s in sides:
                length = rng.uniform(80.0, 200.0)
                u = np.arange(0.0, length + 1.0)[:, None]
                bend = np.sin(np.pi * u / length) * rng.uniform(-10, 10)
                side.append(Road(xy=centre[i] + s * left[i] * u + d[i] * bend, width_m=float(rng.uniform(6.5, 8.0))))
        i += int(rng.uniform(60, 140))
    bounds = [0] + cuts + [len(centre) - 1]
    main = [Road(xy=centre[a : b + 1], width_m=width_m) for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= 2]
    styles = rng.choice(4, size=len(junctions), p=[0.45, 0.3, 0.13, 0.12])
    return main + side, np.asarray(junctions, dtype=np.float64).reshape(-1, 2), styles


def build_along_world(out: Path, drive_dir: Path, seed: int = 0, progress: bool = True) -> Path:
    """World around the KITTI raw drive at `drive_dir` (see module docstring); returns `out`."""
    kd = load_drive(drive_dir)
    out.mkdir(parents=True, exist_ok=True)
    r_layout, r_paint, r_roads = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    steps = tqdm(total=3, desc="world", unit="step", disable=not progress)
    origin = kd.origin_utm
    centre_utm = (float(origin[0]), float(origin[1]))
    track = kd.truth.xy
    roads, junctions, styles = roads_along(track, r_roads)
    x0, y0, x1, y1, w, h = world_extent(track, centre_utm)
    scene = layout_scene(r_layout, (x0, y0, x1, y1), roads, junctions, styles)
    steps.update()
    mosaic_name = paint_and_write(scene, out, x0, y1, w, h, kd.utm_epsg, centre_utm, seed, r_paint, progress)
    steps.update()

    date = kd.name.split("_drive_")[0]
    drive_rel = Path(date) / f"{kd.name}_sync"
    stamps = (Path(drive_dir) / "oxts" / "timestamps.txt").read_text().split("\n")
    stamps = [s.strip() for s in stamps if s.strip()]
    kw.write_oxts(out / drive_rel / "oxts", kd.oxts, stamps)
    t = kd.imu.t
    rate = (len(t) - 1) / max(float(t[-1]), 1e-9)
    every = max(1, int(round(rate / 10.0)))
    kw.write_timestamps(out / drive_rel / "frames" / "timestamps.txt", stamps[::every])
    cam = CameraConfig()
    kw.write_calib(out / date, cam)
    o = kd.oxts
    utm = track + origin
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(track, axis=0), axis=1))]
    np.savez_compressed(out / "truth.npz", t=t, utm=utm, heading=kd.truth.heading,
                        speed=np.hypot(o[:, OXTS["vn"]], o[:, OXTS["ve"]]), yaw_rate=o[:, OXTS["wz"]],
                        accel_fwd=o[:, OXTS["af"]], accel_lat=o[:, OXTS["al"]], s=s, lat=o[:, OXTS["lat"]],
                        lon=o[:, OXTS["lon"]], convergence=np.full(len(t), kd.convergence_rad), frame_t=t[::every],
                        origin_utm=origin, epsg=np.int64(kd.utm_epsg))
    meta = {
        "generator": GENERATOR_VERSION, "seed": seed, "crs_epsg": kd.utm_epsg,
        "centre": [kd.start.lat, kd.start.lon], "centre_utm": list(centre_utm), "mosaic": mosaic_name,
        "m_per_px": M_PER_PX, "drive": drive_rel.as_posix(), "drive_name": kd.name, "truth": "truth.npz",
        "frames": (drive_rel / "frames" / "timestamps.txt").as_posix(), "imu_rate_hz": rate,
        "frame_rate_hz": rate / every, "imu_noise": "real (KITTI OXTS RT3003)", "camera": asdict(cam),
        "length_m": float(s[-1]), "duration_s": float(t[-1]), "along_drive": kd.name, "realism": "flat",
    }
    (out / "world.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    steps.update()
    steps.close()
    log.info("world along %s: %.0f m, %d side-street junctions", kd.name, s[-1], len(junctions))
    return out
