"""What the simulated autopilot plays: one drive (KITTI raw or a synthetic world) as flat arrays.

Frames and units: `t` (N,) seconds from the drive's first sample; IMU in body FRD (specific force m/s^2 with
gravity, gyro rad/s) and NED roll/pitch/yaw radians, exactly as the dataset readers give them (the IMU yaw
is the true, geographic heading, with the dataset's own noise). The GNSS reading (`lat`, `lon` degrees WGS84,
`alt` m, `vn`, `ve` m/s) comes from the OXTS packets. The true pose for SIMSTATE (`true_lat`, `true_lon`,
`true_yaw_ned` radians, 0 = north, CW) comes from the ground truth: for a synthetic world the generator's
exact truth (its OXTS attitude carries IMU noise), for KITTI the OXTS solution itself. `utc0` is the UTC unix
time of the first sample, seconds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taco_mav.datasets.base import GroundTruth
from taco_mav.datasets.kitti import OXTS, KittiDrive, load_drive
from taco_mav.errors import DataError
from taco_mav.geo import UtmProjector, wrap_angle

log = logging.getLogger(__name__)

__all__ = ["SimDrive", "open_drive"]


@dataclass(frozen=True, eq=False)
class SimDrive:
    """A drive ready to be played (see the module docstring for frames and units)."""

    name: str
    path: Path
    t: np.ndarray
    accel_frd: np.ndarray
    gyro_frd: np.ndarray
    rpy_ned: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    vn: np.ndarray
    ve: np.ndarray
    true_lat: np.ndarray
    true_lon: np.ndarray
    true_yaw_ned: np.ndarray
    truth: GroundTruth
    origin_utm: np.ndarray
    utm_epsg: int
    utc0: float
    world_dir: Path | None = None
    t0_autopilot: float | None = None  # a recording: sample 0 plays at this autopilot time (its recorded one)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def duration_s(self) -> float:
        """Time span of the drive, seconds."""
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0

    @property
    def data_rate_hz(self) -> float:
        """Median IMU sample rate, Hz."""
        return float(1.0 / np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0

    def index_at(self, t: float) -> int:
        """Index of the last sample at or before time t (clamped to the drive)."""
        return int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1))


def _true_pose(t: np.ndarray, truth: GroundTruth, origin_utm: np.ndarray, epsg: int) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The truth at times t (s, the truth's clock): lat, lon (degrees WGS84), yaw NED (true, radians), and the
    grid east / north (UTM metres) they come from."""
    proj = UtmProjector(epsg)
    e = origin_utm[0] + np.interp(t, truth.t, truth.xy[:, 0])
    n = origin_utm[1] + np.interp(t, truth.t, truth.xy[:, 1])
    lat, lon = (np.atleast_1d(v) for v in proj.to_latlon(e, n))
    conv = np.asarray(proj.grid_convergence(lat, lon), dtype=float)
    heading_grid = np.interp(t, truth.t, np.unwrap(truth.heading))
    return lat, lon, np.atleast_1d(wrap_angle(math.pi / 2.0 - (heading_grid - conv))), e, n


def _from_kitti(kd: KittiDrive, truth: GroundTruth, origin_utm: np.ndarray, world_dir: Path | None) -> SimDrive:
    ox = kd.oxts
    true_lat, true_lon, true_yaw_ned, _, _ = _true_pose(kd.imu.t, truth, origin_utm, kd.utm_epsg)
    return SimDrive(
        name=kd.name, path=kd.path, t=kd.imu.t - kd.imu.t[0], accel_frd=kd.imu.accel_frd, gyro_frd=kd.imu.gyro_frd,
        rpy_ned=kd.imu.rpy_ned, lat=ox[:, OXTS["lat"]], lon=ox[:, OXTS["lon"]], alt=ox[:, OXTS["alt"]],
        vn=ox[:, OXTS["vn"]], ve=ox[:, OXTS["ve"]], true_lat=true_lat, true_lon=true_lon, true_yaw_ned=true_yaw_ned,
        truth=truth, origin_utm=np.asarray(origin_utm, dtype=float),
        utm_epsg=kd.utm_epsg, utc0=float(kd.t0_unix), world_dir=world_dir)


def _from_recording(tlog: Path) -> SimDrive:
    """A daemon's recorded session (`taco-mav run --log-dir --record`): its IMU and attitude, and the real
    receiver's fixes as both the GNSS reading and the truth, on the recorded autopilot clock (`t0_autopilot`), so
    that `--camera folder:SESSION/frames` serves the recorded frames at their own times."""
    from taco_mav.datasets.tlog import load_tlog

    td = load_tlog(tlog)
    t, truth = td.imu.t, td.truth
    lat, lon, true_yaw_ned, e, n = _true_pose(t, truth, td.origin_utm, td.utm_epsg)
    vn, ve = np.gradient(n, t), np.gradient(e, t)  # grid north/east, m/s (convergence: well under 1 %)
    return SimDrive(
        name=Path(tlog).resolve().parent.name, path=Path(tlog), t=t - t[0], accel_frd=td.imu.accel_frd,
        gyro_frd=td.imu.gyro_frd, rpy_ned=td.imu.rpy_ned, lat=lat, lon=lon, alt=np.full(len(t), td.start.alt),
        vn=vn, ve=ve, true_lat=lat, true_lon=lon, true_yaw_ned=true_yaw_ned,
        truth=GroundTruth(truth.t - t[0], truth.xy, truth.heading), origin_utm=np.asarray(td.origin_utm, float),
        utm_epsg=td.utm_epsg, utc0=td.t0_unix, t0_autopilot=float(t[0]))


def open_drive(path: Path) -> SimDrive:
    """Open a KITTI raw drive folder (`..._sync` with `oxts/`), a synthetic world folder (`world.json`), or a
    recorded session (its mav.tlog, or the session folder holding it).

    Raises DataError (naming the path) when it is neither or its files are malformed.
    """
    path = Path(path)
    if (path / "world.json").is_file():
        from taco_mav.datasets.synthetic import load_world

        world = load_world(path)
        drive = _from_kitti(world.kitti, world.truth, world.origin_utm, path)
    elif (path / "oxts").is_dir():
        kd = load_drive(path)
        drive = _from_kitti(kd, kd.truth, kd.origin_utm, None)
    elif path.suffix == ".tlog" or (path / "mav.tlog").is_file():
        drive = _from_recording(path if path.suffix == ".tlog" else path / "mav.tlog")
    else:
        raise DataError(f"{path}: neither a KITTI raw drive folder (oxts/), a synthetic world (world.json) nor a "
                        "recorded session (mav.tlog)")
    if len(drive) < 2:
        raise DataError(f"{path}: the drive has {len(drive)} samples; at least 2 are needed to play it")
    if np.any(np.diff(drive.t) <= 0):
        raise DataError(f"{path}: sample times are not strictly increasing")
    log.info("sim drive %s: %d samples at %.0f Hz over %.1f s, %.2f km", drive.name, len(drive),
             drive.data_rate_hz, drive.duration_s, drive.truth.length_m() / 1000.0)
    return drive
