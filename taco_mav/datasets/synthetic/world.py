"""`build_world`: a synthetic satellite mosaic plus a drive through it, written in KITTI raw layout.

Output (`out` is the world folder):
  out/world.json                      CRS, seed, generator version, centre, noise model, camera, file names
  out/mosaic.tif                      RGB uint8 GeoTIFF, UTM (EPSG:326xx/327xx), north-up, 0.2 m/px, deflate
  out/truth.npz                       exact truth at the IMU rate (UTM metres, grid heading, speed, ...)
  out/<date>/calib_cam_to_cam.txt     (+ calib_velo_to_cam.txt, calib_imu_to_velo.txt)
  out/<date>/<date>_drive_<nnnn>_sync/oxts/{data/%010d.txt, timestamps.txt, dataformat.txt}   100 Hz
  out/<date>/<date>_drive_<nnnn>_sync/frames/timestamps.txt    camera frame times, 10 Hz (KITTI format)

Frames: the local frame is ENU metres relative to the world centre; the truth is in UTM metres of the
centre's zone with headings on the UTM grid (0 = east, CCW). OXTS yaw, vn and ve are true (geographic) as a
real OXTS unit reports them: yaw_oxts = heading_grid - meridian convergence, which the KITTI reader adds back.
Camera frame times sit in `frames/`, not `image_02/`: the KITTI reader expects one image per OXTS packet in
`image_02/` (sync layout), and synthetic frames are rendered on demand, not stored.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from taco_mav.config import CameraConfig
from taco_mav.datasets.synthetic import kitti_writer as kw
from taco_mav.datasets.synthetic.imu_model import ImuNoiseModel, apply_imu_noise, noise_preset
from taco_mav.datasets.synthetic.layout import layout_scene
from taco_mav.datasets.synthetic.roads import Road, grid_network, plan_route, route_polyline
from taco_mav.datasets.synthetic.trajectory import Kinematics, drive_kinematics
from taco_mav.datasets.synthetic.world_base import GENERATOR_VERSION, M_PER_PX, paint_and_write, world_extent
from taco_mav.errors import ConfigError
from taco_mav.geo import UtmProjector, utm_epsg_for

log = logging.getLogger(__name__)

__all__ = ["build_world", "GENERATOR_VERSION", "DEFAULT_CENTRE", "G"]

DEFAULT_CENTRE = (49.01, 8.40)  # near Karlsruhe (UTM zone 32N), KITTI's city
G = 9.80665
IMU_RATE_HZ = 100.0
FRAME_RATE_HZ = 10.0
DATE = "2011_01_01"
DRIVE = 1
START_TIME = _dt.datetime(2011, 1, 1, 12, 0, 0)
ALT_M = 115.0


def _stubs(net_nodes: np.ndarray, net_edges: np.ndarray, roads: list[Road]) -> list[Road]:
    """Roads leaving the grid outwards from its boundary junctions (degree 3), 250 m long, drawn only."""
    deg = np.bincount(net_edges.ravel(), minlength=len(net_nodes))
    out = []
    for k in np.flatnonzero(deg == 3):
        nb = [b if a == k else a for a, b in net_edges if k in (a, b)]
        d = net_nodes[k] - net_nodes[nb].mean(axis=0)
        if np.linalg.norm(d) < 1e-6:
            continue
        d /= np.linalg.norm(d)
        u = np.arange(0.0, 251.0)[:, None]
        out.append(Road(xy=net_nodes[k] + u * d, width_m=7.0))
    return out


def _keep_clear_local(lines: Sequence[Sequence[tuple[float, float]]], proj: UtmProjector, lat0: float,
                      lon0: float) -> list[np.ndarray]:
    """(east, north) metres from the centre (true north, equirectangular as a ground station's mission offsets)
    -> local grid metres (UTM minus the centre's), one (N, 2) array per polyline."""
    r = 6378137.0
    e0, n0 = proj.to_utm(lat0, lon0)
    out = []
    for line in lines:
        en = np.asarray(line, np.float64).reshape(-1, 2)
        lat = lat0 + np.degrees(en[:, 1] / r)
        lon = lon0 + np.degrees(en[:, 0] / (r * math.cos(math.radians(lat0))))
        pts = [proj.to_utm(float(a), float(b)) for a, b in zip(lat, lon)]
        out.append(np.array([(e - e0, n - n0) for e, n in pts], np.float64))
    return out


def _densify(line: np.ndarray, step_m: float) -> np.ndarray:
    """Points along polyline `line` (N, 2) no more than `step_m` apart, its vertices included."""
    pts = [line[:1]]
    for a, b in itertools.pairwise(line):
        k = max(1, math.ceil(float(np.linalg.norm(b - a)) / step_m))
        pts.append(a + (b - a) * (np.arange(1, k + 1)[:, None] / k))
    return np.vstack(pts)


def _oxts_rows(kin: Kinematics, proj: UtmProjector, centre_utm: tuple[float, float], model: ImuNoiseModel,
               seed: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(N, 30) OXTS values for the kinematics, and the exact truth arrays for truth.npz."""
    n = len(kin.t)
    e, nn = kin.xy[:, 0] + centre_utm[0], kin.xy[:, 1] + centre_utm[1]
    lat, lon = proj.to_latlon(e, nn)
    conv = np.asarray(proj.grid_convergence(lat, lon))
    heading_grid = np.mod(kin.heading + math.pi, 2 * math.pi) - math.pi
    true_heading = kin.heading - conv
    accel = np.c_[kin.accel_fwd, kin.accel_lat, np.full(n, G)]
    gyro = np.c_[np.zeros(n), np.zeros(n), kin.yaw_rate]
    rpy = np.c_[np.zeros(n), np.zeros(n), true_heading]
    a_n, g_n, rpy_n = apply_imu_noise(model, accel, gyro, rpy, 1.0 / IMU_RATE_HZ, seed)
    v = kin.speed
    cols = {
        "lat": lat, "lon": lon, "alt": np.full(n, ALT_M), "roll": rpy_n[:, 0], "pitch": rpy_n[:, 1],
        "yaw": rpy_n[:, 2], "vn": v * np.sin(true_heading), "ve": v * np.cos(true_heading), "vf": v,
        "vl": np.zeros(n), "vu": np.zeros(n), "ax": a_n[:, 0], "ay": a_n[:, 1], "az": a_n[:, 2],
        "af": a_n[:, 0], "al": a_n[:, 1], "au": a_n[:, 2], "wx": g_n[:, 0], "wy": g_n[:, 1], "wz": g_n[:, 2],
        "wf": g_n[:, 0], "wl": g_n[:, 1], "wu": g_n[:, 2], "pos_accuracy": np.full(n, 0.05),
        "vel_accuracy": np.full(n, 0.02), "navstat": np.full(n, 4), "numsats": np.full(n, 10),
        "posmode": np.full(n, 4), "velmode": np.full(n, 4), "orimode": np.full(n, 4),
    }
    values = np.column_stack([cols[f] for f in kw.OXTS_FIELDS])
    truth = dict(t=kin.t, utm=np.c_[e, nn], heading=heading_grid, speed=kin.speed, yaw_rate=kin.yaw_rate,
                 accel_fwd=kin.accel_fwd, accel_lat=kin.accel_lat, s=kin.s, lat=lat, lon=lon,
                 convergence=conv)
    return values, truth


def build_world(out: Path, seed: int = 0, length_km: float = 1.0, centre: tuple[float, float] | None = None,
                along_drive: Path | None = None, imu_preset: str = "automotive", progress: bool = True,
                realism: str = "flat", keep_clear: Sequence[Sequence[tuple[float, float]]] = ()) -> Path:
    """Generate a world (mosaic + drive in KITTI raw layout) into `out`; returns `out`.

    seed: every random choice derives from it (same seed, same bytes). length_km: approximate route length
    (at least one block loop plus the revisited street, so very short requests come out longer).
    centre: (lat, lon) degrees of the world centre (default 49.01 N 8.40 E). along_drive: a KITTI raw drive
    folder; the roads then follow its GPS track and its real OXTS is written (see `along.py`).
    imu_preset: automotive | rt3003 | none (ignored with along_drive: the real IMU is kept).
    realism: "flat" (the mosaic is the ground) or "3d" (buildings, trees, cars, poles; the mosaic is an
    aerial render of another day with a georeferencing error: see `world3d.py`).
    keep_clear: polylines of (east, north) metres from the centre (true north, as a ground station lays out a
    mission) that another vehicle drives, e.g. a SITL mission's square: buildings, lots, trees, poles and parked
    cars keep clear of them (`layout.KEEP_CLEAR_M`) as they do of the drive. Empty: the world is unchanged.
    """
    model = noise_preset(imu_preset)
    if realism not in ("flat", "3d"):
        raise ConfigError(f"--realism: {realism!r} is not one of flat, 3d")
    if realism == "3d" and along_drive is not None:
        raise ConfigError("--realism 3d: not available with --along-drive yet")
    if along_drive is not None and keep_clear:
        raise ConfigError("--keep-clear: not available with --along-drive")
    if along_drive is not None:
        from taco_mav.datasets.synthetic.along import build_along_world

        return build_along_world(Path(out), Path(along_drive), seed=seed, progress=progress)
    if not (0.05 <= length_km <= 50.0):
        raise ConfigError(f"--length-km: {length_km} is out of range (0.05 .. 50 km)")
    lat0, lon0 = centre if centre is not None else DEFAULT_CENTRE
    epsg = utm_epsg_for(lat0, lon0)
    proj = UtmProjector(epsg)
    centre_utm = tuple(float(v) for v in proj.to_utm(lat0, lon0))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ss = np.random.SeedSequence(seed)
    r_roads, r_drive, r_layout, r_paint = (np.random.default_rng(s) for s in ss.spawn(4))
    steps = tqdm(total=5, desc="world", unit="step", disable=not progress)

    length_m = 1000.0 * length_km
    n = int(np.clip(math.ceil(math.sqrt(length_m / 100.0 / 2.0)) + 1, 3, 14))
    net = grid_network(r_roads, n, n)
    route = plan_route(net, r_roads, length_m)
    line, junction_idx, offset = route_polyline(net, route)
    kin = drive_kinematics(line, junction_idx, r_drive, offset_right=offset, rate_hz=IMU_RATE_HZ)
    log.info("route: %d junctions, %.0f m, %.0f s", len(route), kin.s[-1], kin.t[-1])
    steps.update()

    x0, y0, x1, y1, w, h = world_extent(kin.xy, centre_utm)
    roads = net.roads + _stubs(net.nodes, net.edges, net.roads)
    clear = _keep_clear_local(keep_clear, proj, lat0, lon0)
    scene = layout_scene(r_layout, (x0, y0, x1, y1), roads, net.nodes, net.junction_style, keep_clear=clear)
    steps.update()
    extra: dict = {}
    if realism == "3d":
        from taco_mav.datasets.synthetic.world3d import build_world3d

        clear_xy = np.vstack([_densify(c, 0.5) for c in clear]) if clear else None
        extra = build_world3d(out, scene, (x0, y0, x1, y1), epsg, centre_utm, seed, kin.xy, kin.t, progress,
                              clear_xy=clear_xy)
        mosaic_name = extra["mosaic"]
    else:
        mosaic_name = paint_and_write(scene, out, x0, y1, w, h, epsg, centre_utm, seed, r_paint, progress)
    steps.update()

    values, truth = _oxts_rows(kin, proj, centre_utm, model, seed)
    drive_name = kw.drive_dir_name(DATE, DRIVE)
    drive_rel = Path(DATE) / drive_name
    stamps = kw.kitti_timestamps(START_TIME, kin.t)
    kw.write_oxts(out / drive_rel / "oxts", values, stamps)
    every = int(round(IMU_RATE_HZ / FRAME_RATE_HZ))
    frame_t = kin.t[::every]
    kw.write_timestamps(out / drive_rel / "frames" / "timestamps.txt", stamps[::every])
    cam = CameraConfig()
    kw.write_calib(out / DATE, cam)
    steps.update()

    np.savez_compressed(out / "truth.npz", frame_t=frame_t, origin_utm=truth["utm"][0], epsg=np.int64(epsg), **truth)
    meta = {
        "generator": GENERATOR_VERSION, "seed": seed, "crs_epsg": epsg, "centre": [lat0, lon0],
        "centre_utm": list(centre_utm), "mosaic": mosaic_name, "m_per_px": M_PER_PX,
        "drive": drive_rel.as_posix(), "drive_name": drive_name.removesuffix("_sync"), "truth": "truth.npz",
        "frames": (drive_rel / "frames" / "timestamps.txt").as_posix(), "imu_rate_hz": IMU_RATE_HZ,
        "frame_rate_hz": FRAME_RATE_HZ, "imu_noise": model.to_dict(), "camera": asdict(cam),
        "length_m": float(kin.s[-1]), "duration_s": float(kin.t[-1]), "along_drive": None, "realism": realism,
    }
    if clear:
        meta["keep_clear_en_m"] = [[list(map(float, p)) for p in line] for line in keep_clear]
    meta.update(extra)
    (out / "world.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    steps.update()
    steps.close()
    return out
