"""Synthetic world: determinism, KITTI-layout round trip, IMU physics, dead reckoning, revisit, mosaic, frames."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
import rasterio

from taco_mav.datasets.kitti import load_drive
from taco_mav.datasets.synthetic import build_world, load_world
from taco_mav.geo import utm_epsg_for

LENGTH_KM = 0.3


def _digest(world: Path, pattern: str) -> str:
    h = hashlib.sha256()
    for p in sorted(world.glob(pattern)):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def worlds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("worlds")
    out = {}
    for key, seed, imu in (("a", 0, "automotive"), ("a2", 0, "automotive"), ("b", 1, "automotive"), ("clean", 0, "none")):
        out[key] = build_world(root / key, seed=seed, length_km=LENGTH_KM, imu_preset=imu, progress=False)
    return out


def _drive_dir(world: Path) -> Path:
    return world / json.loads((world / "world.json").read_text())["drive"]


def test_same_seed_same_bytes_different_seed_differs(worlds):
    a, a2, b = worlds["a"], worlds["a2"], worlds["b"]
    assert (a / "mosaic.tif").read_bytes() == (a2 / "mosaic.tif").read_bytes()
    oxts = "2011_01_01/*_sync/oxts/data/*.txt"
    assert _digest(a, oxts) == _digest(a2, oxts)
    assert _digest(a, "2011_01_01/*_sync/oxts/timestamps.txt") == _digest(a2, "2011_01_01/*_sync/oxts/timestamps.txt")
    assert (a / "world.json").read_text() == (a2 / "world.json").read_text()
    assert (a / "mosaic.tif").read_bytes() != (b / "mosaic.tif").read_bytes()
    assert _digest(a, oxts) != _digest(b, oxts)


def test_loads_through_kitti_reader_at_100hz(worlds):
    world = worlds["a"]
    meta = json.loads((world / "world.json").read_text())
    kd = load_drive(_drive_dir(world))
    assert len(kd.imu) == int(round(meta["duration_s"] * 100.0)) + 1
    assert np.allclose(np.diff(kd.imu.t), 0.01, atol=1e-9)
    assert kd.mosaic == (world / "mosaic.tif").resolve()
    assert kd.utm_epsg == meta["crs_epsg"] == utm_epsg_for(49.01, 8.40) == 32632
    assert kd.camera is not None and (kd.camera.width, kd.camera.height) == (1242, 375)
    assert kd.camera.K[0, 0] == pytest.approx(721.5377, abs=1e-3)
    frames = (_drive_dir(world) / "frames" / "timestamps.txt").read_text().splitlines()
    assert len(frames) == (len(kd.imu) - 1) // 10 + 1


def test_level_vehicle_at_rest_reads_minus_g_in_frd(worlds):
    kd = load_drive(_drive_dir(worlds["a"]))
    rest = kd.imu.accel_frd[:200]  # the drive starts with 3 s at rest
    assert rest[:, 2].mean() == pytest.approx(-9.80665, abs=0.05)
    assert np.all(np.abs(rest[:, :2].mean(axis=0)) < 0.08)
    clean = load_drive(_drive_dir(worlds["clean"]))
    assert np.allclose(clean.imu.accel_frd[:150], [0.0, 0.0, -9.80665], atol=1e-9)
    assert np.allclose(clean.imu.gyro_frd[:150], 0.0, atol=1e-12)


def _dead_reckon(world: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """Integrate forward specific force to speed and take heading from the attitude (grid heading = true
    heading + meridian convergence); returns (dr xy, truth xy, path length)."""
    d = load_world(world)
    imu = d.imu
    dt = np.diff(imu.t)
    v = np.r_[0.0, np.cumsum(0.5 * (imu.accel_frd[1:, 0] + imu.accel_frd[:-1, 0]) * dt)]
    theta = math.pi / 2.0 - imu.rpy_ned[:, 2] + d.kitti.convergence_rad
    step = (v[:, None] * np.c_[np.cos(theta), np.sin(theta)])
    xy = np.r_[[[0.0, 0.0]], np.cumsum(0.5 * (step[1:] + step[:-1]) * dt[:, None], axis=0)]
    return xy, d.truth.xy, d.truth.length_m()


def test_dead_reckoning_noise_free_reproduces_truth(worlds):
    xy, truth, length = _dead_reckon(worlds["clean"])
    err = np.linalg.norm(xy - truth, axis=1)
    assert err.max() < 0.01 * length


def test_dead_reckoning_automotive_drifts_plausibly(worlds):
    """Automotive preset, 0.3 km request (~0.35-0.5 km, ~1 min): the accelerometer residual bias (3 mg) and
    vibration make the integrated speed wander; the final drift is a few metres to a few tens of metres."""
    xy, truth, length = _dead_reckon(worlds["a"])
    final = float(np.linalg.norm(xy[-1] - truth[-1]))
    assert 0.5 < final < 0.25 * length


def test_route_revisits_a_street(worlds):
    d = load_world(worlds["a"])
    xy = d.truth.xy[::20]
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(d.truth.xy, axis=0), axis=1))][::20]
    close = np.linalg.norm(xy[:, None] - xy[None], axis=2) <= 10.0
    far_along = np.abs(s[:, None] - s[None]) >= 200.0
    assert np.any(close & far_along)


def test_mosaic_georeferenced_bounded_and_textured(worlds):
    world = worlds["a"]
    d = load_world(world)
    with rasterio.open(world / "mosaic.tif") as src:
        assert src.crs.to_epsg() == 32632
        assert src.res == pytest.approx((0.2, 0.2))
        assert src.count == 3 and src.dtypes[0] == "uint8"
        assert src.profile["compress"] == "deflate"
        b = src.bounds
        img = src.read().transpose(1, 2, 0)
        T = src.transform
    utm = d.truth_utm
    assert b.left <= utm[:, 0].min() - 149 and b.right >= utm[:, 0].max() + 149
    assert b.bottom <= utm[:, 1].min() - 149 and b.top >= utm[:, 1].max() + 149
    assert b.right - b.left <= (np.ptp(utm[:, 0]) + 302) and b.top - b.bottom <= (np.ptp(utm[:, 1]) + 302)
    grey = img.astype(np.float32).mean(axis=2)
    for e, n in utm[:: len(utm) // 5]:
        col, row = ~T @ (e, n)
        crop = grey[int(row) - 250 : int(row) + 250, int(col) - 250 : int(col) + 250]  # 100 m
        for k in (1, 4, 16):  # 0.2 m, 0.8 m, 3.2 m: structure at every scale
            small = crop[::k, ::k]
            assert np.abs(np.diff(small, axis=1)).mean() > 2.0


def test_frames_render_from_true_pose_on_the_road(worlds):
    d = load_world(worlds["a"])
    assert np.allclose(np.diff(d.frame_times), 0.1, atol=1e-9)
    f = d.frame(len(d.frame_times) // 2)
    assert f.shape == (375, 1242, 3) and f.dtype == np.uint8
    road = f[330:375, 560:680].astype(np.float32)  # the ground just ahead of the bumper
    assert 50 < road.mean() < 140  # asphalt grey, not grass or sky
    assert np.abs(road[..., 1] - road[..., 0]).mean() < 12  # unsaturated
    assert not np.array_equal(d.frame(10), d.frame(40))


def test_along_real_kitti_drive(kitti_root: Path, tmp_path: Path):
    src = kitti_root / "2011_09_26" / "2011_09_26_drive_0005_sync"
    world = build_world(tmp_path / "along", seed=0, along_drive=src, progress=False)
    real = load_drive(src)
    d = load_world(world)
    assert d.name == real.name and len(d.imu) == len(real.imu)
    assert np.allclose(d.kitti.oxts, real.oxts, rtol=1e-12, atol=1e-12)
    assert np.allclose(d.truth.xy, real.truth.xy, atol=1e-6)
    with rasterio.open(d.mosaic) as m:
        b = m.bounds
    assert b.left < d.truth_utm[:, 0].min() - 100 and b.top > d.truth_utm[:, 1].max() + 100
    f = d.frame(len(d.frame_times) // 2)
    assert 50 < f[330:375, 560:680].mean() < 140  # the real track is drawn as a road
