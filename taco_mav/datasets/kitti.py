"""KITTI raw ("sync") drives as `Drive`s: OXTS converted to an autopilot's FRD/NED view, UTM ground truth.

Layout read: `<root>/<date>/<date>_drive_<nnnn>_sync/oxts/{data/<i:010d>.txt, timestamps.txt}`, optionally
`image_02/{data/<i:010d>.png, timestamps.txt}` and `<root>/<date>/calib_cam_to_cam.txt`.

Conversions (oxts/dataformat.txt, checked against the real drives in tests/test_kitti.py):
- OXTS body axes are FLU (x forward, y left, z up); FRD negates y and z. ax..az are specific force (gravity
  included: a level vehicle at rest reads az = +9.81, so accel_frd z = -9.81); wx..wz are FLU body rates.
- OXTS roll is positive left side up = NED roll (right side down); OXTS pitch is positive front down, NED pitch
  positive nose up, so pitch_ned = -pitch; OXTS yaw is ENU (0 = east, CCW), yaw_ned = wrap(pi/2 - yaw).
- Times: the timestamp strings are read as UTC (KITTI states no zone); streams use drive-relative seconds
  starting at 0 at the first loaded frame; `t0_unix` keeps the absolute time.
- Ground truth: OXTS lat/lon projected to the UTM zone of the first loaded fix; xy relative to that fix;
  heading = OXTS yaw turned onto the UTM grid (plus the meridian convergence, about -0.46 deg at Karlsruhe),
  so that it is the direction of motion in the xy frame. The IMU yaw and the start fix's course stay true
  (referenced to geographic north), as an autopilot and a GNSS receiver report them.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig
from taco_mav.datasets.base import GroundTruth, ImuStream, StartFix, WheelLog
from taco_mav.datasets.kitti_io import (
    OXTS,
    OXTS_FIELDS,
    calib_numbers,
    count_files,
    find_world_mosaic,
    read_calib,
    read_oxts,
    read_timestamps,
)
from taco_mav.errors import DataError
from taco_mav.geo import UtmProjector, utm_epsg_for, wrap_angle

log = logging.getLogger(__name__)

__all__ = [
    "ODOMETRY_SEQUENCES",
    "OXTS",
    "OXTS_FIELDS",
    "KittiDrive",
    "OdometrySequence",
    "camera_from_calib",
    "default_kitti_root",
    "load_drive",
    "load_sequence",
    "oxts_to_imu",
    "sequence_drive_dir",
]


@dataclass(frozen=True)
class OdometrySequence:
    """Where a KITTI odometry sequence lives in the raw data: `drive_name` frames first..last inclusive."""

    date: str
    drive: int
    first: int
    last: int

    @property
    def drive_name(self) -> str:
        """E.g. "2011_09_30_drive_0018"."""
        return f"{self.date}_drive_{self.drive:04d}"

    @property
    def frames(self) -> slice:
        """The sequence's frames as a slice of the raw drive."""
        return slice(self.first, self.last + 1)


ODOMETRY_SEQUENCES: dict[str, OdometrySequence] = {
    "00": OdometrySequence("2011_10_03", 27, 0, 4540),
    "01": OdometrySequence("2011_10_03", 42, 0, 1100),
    "02": OdometrySequence("2011_10_03", 34, 0, 4660),
    "03": OdometrySequence("2011_09_26", 67, 0, 800),
    "04": OdometrySequence("2011_09_30", 16, 0, 270),
    "05": OdometrySequence("2011_09_30", 18, 0, 2760),
    "06": OdometrySequence("2011_09_30", 20, 0, 1100),
    "07": OdometrySequence("2011_09_30", 27, 0, 1100),
    "08": OdometrySequence("2011_09_30", 28, 1100, 5170),
    "09": OdometrySequence("2011_09_30", 33, 0, 1590),
    "10": OdometrySequence("2011_09_30", 34, 0, 1200),
}


@dataclass(frozen=True, eq=False)
class KittiDrive:
    """One KITTI raw drive (or a slice of it) behind the `Drive` protocol (see datasets/base.py for units).

    Beyond the protocol: `convergence_rad` is the meridian convergence at the origin (UTM grid heading = true
    heading + convergence_rad; `truth.heading` is on the grid, `imu.rpy_ned` yaw is true); `path` is the
    drive folder; `first_index` the raw frame index of element 0; `t0_unix` the UTC unix time, s, of element
    0; `t_unix` (N,) UTC unix times, s; `oxts` (N, 30) the raw OXTS packets (columns `OXTS_FIELDS`, index
    them with `OXTS["vn"]`, ...). `camera` is built from the
    date's calib_cam_to_cam.txt whenever it exists, even for drives stored without images.
    """

    name: str
    sequence: str | None
    imu: ImuStream
    truth: GroundTruth
    start: StartFix
    utm_epsg: int
    origin_utm: np.ndarray
    convergence_rad: float
    frame_times: np.ndarray
    camera: GroundCamera | None
    mosaic: Path | None
    path: Path
    first_index: int
    t0_unix: float
    t_unix: np.ndarray
    oxts: np.ndarray
    _image_paths: tuple[Path, ...] = field(default=(), repr=False)
    wheels: WheelLog | None = None  # KITTI's car logs no wheel encoders

    def __len__(self) -> int:
        return len(self.imu)

    def frame(self, index: int) -> np.ndarray:
        """Camera frame `index` (0 = first loaded frame) as uint8 RGB (H, W, 3), from image_02."""
        if not self._image_paths:
            raise DataError(f"{self.path}: drive {self.name} has no camera images (image_02 folder absent)")
        if not 0 <= index < len(self._image_paths):
            raise DataError(f"{self.path}: frame {index} out of range (drive has {len(self._image_paths)} frames)")
        path = self._image_paths[index]
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DataError(f"{path}: image missing or not readable")
        if self.camera is not None and bgr.shape[:2] != (self.camera.height, self.camera.width):
            raise DataError(f"{path}: image is {bgr.shape[1]}x{bgr.shape[0]} px, calibration says "
                            f"{self.camera.width}x{self.camera.height}")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def oxts_to_imu(t: np.ndarray, oxts: np.ndarray) -> ImuStream:
    """OXTS packets (N, 30) at times t (N,) s -> FRD specific force and rates, NED roll/pitch/yaw (radians)."""
    flu_to_frd = np.array([1.0, -1.0, -1.0])
    accel = oxts[:, [OXTS["ax"], OXTS["ay"], OXTS["az"]]] * flu_to_frd
    gyro = oxts[:, [OXTS["wx"], OXTS["wy"], OXTS["wz"]]] * flu_to_frd
    rpy = np.column_stack([
        oxts[:, OXTS["roll"]],
        -oxts[:, OXTS["pitch"]],
        wrap_angle(math.pi / 2.0 - oxts[:, OXTS["yaw"]]),
    ])
    return ImuStream(np.asarray(t, dtype=np.float64), accel, gyro, rpy)


def camera_from_calib(path: Path, mount_height_m: float) -> GroundCamera:
    """The rectified left colour camera (P_rect_02, S_rect_02) of a calib_cam_to_cam.txt, level, at
    `mount_height_m` metres above a flat ground."""
    calib = read_calib(path)
    P = calib_numbers(calib, "P_rect_02", 12, path).reshape(3, 4)
    width, height = calib_numbers(calib, "S_rect_02", 2, path)
    if P[0, 0] <= 0 or P[1, 1] <= 0 or width < 1 or height < 1:
        raise DataError(f"{path}: P_rect_02/S_rect_02 do not describe a camera (fx {P[0, 0]}, size {width}x{height})")
    K = P[:, :3].copy()
    return GroundCamera(K, int(round(width)), int(round(height)), mount_height_m, 0.0)


def _select(n: int, frames: slice | None, where: Path) -> range:
    if frames is None:
        return range(n)
    if frames.step not in (None, 1):
        raise DataError(f"{where}: frame slices must have step 1, got {frames.step}")
    start = 0 if frames.start is None else frames.start
    stop = n if frames.stop is None else frames.stop
    if start < 0 or stop > n or start >= stop:
        raise DataError(f"{where}: frames {start}..{stop - 1} asked for, the drive has frames 0..{n - 1}")
    return range(start, stop)


def load_drive(drive_dir: Path, frames: slice | None = None, *, sequence: str | None = None,
               camera_height_m: float | None = None) -> KittiDrive:
    """Load a KITTI raw sync drive folder, all frames or `frames` (a step-1 slice of raw frame indices).

    camera_height_m: the camera's height above ground for the flat-ground model (default: the camera
    section's default, KITTI's 1.65 m). Raises DataError for missing or malformed files.
    """
    drive_dir = Path(drive_dir)
    if not drive_dir.is_dir():
        raise DataError(f"{drive_dir}: drive folder not found")
    name = drive_dir.name.removesuffix("_sync")
    oxts_dir = drive_dir / "oxts"
    if not oxts_dir.is_dir():
        extra = " (image_02 is present, but a drive without OXTS has no IMU or ground truth)" \
            if (drive_dir / "image_02").is_dir() else ""
        raise DataError(f"{oxts_dir}: OXTS folder not found{extra}")
    stamps_ns = read_timestamps(oxts_dir / "timestamps.txt")
    n = len(stamps_ns)
    n_files = count_files(oxts_dir / "data", ".txt")
    if n_files != n:
        raise DataError(f"{oxts_dir}: data/ holds {n_files} OXTS files but timestamps.txt has {n} lines")
    indices = _select(n, frames, drive_dir)
    oxts = read_oxts(oxts_dir / "data", indices)
    stamps_ns = stamps_ns[indices.start:indices.stop]
    t0_ns = int(stamps_ns[0])
    t = (stamps_ns - t0_ns) * 1e-9
    t_unix = stamps_ns * 1e-9

    lat, lon = oxts[:, OXTS["lat"]], oxts[:, OXTS["lon"]]
    epsg = utm_epsg_for(float(lat[0]), float(lon[0]))
    projector = UtmProjector(epsg)
    east, north = projector.to_utm(lat, lon)
    utm = np.column_stack([east, north])
    origin = utm[0].copy()
    convergence = projector.grid_convergence(lat, lon)
    truth = GroundTruth(t.copy(), utm - origin, wrap_angle(oxts[:, OXTS["yaw"]] + convergence))
    vn, ve = float(oxts[0, OXTS["vn"]]), float(oxts[0, OXTS["ve"]])
    start = StartFix(0.0, float(lat[0]), float(lon[0]), float(oxts[0, OXTS["alt"]]),
                     math.hypot(vn, ve), math.atan2(vn, ve))

    frame_times, image_paths = _images(drive_dir, n, indices, t0_ns)
    calib_path = next((p for p in (drive_dir.parent / "calib_cam_to_cam.txt", drive_dir / "calib_cam_to_cam.txt")
                       if p.is_file()), None)
    height = CameraConfig().mount_height_m if camera_height_m is None else camera_height_m
    camera = camera_from_calib(calib_path, height) if calib_path is not None else None
    if image_paths and camera is None:
        log.warning("%s: image_02 present but no calib_cam_to_cam.txt: camera model unknown", drive_dir)
    log.info("%s: %d OXTS samples over %.1f s, %d frames, UTM EPSG:%d", name, len(indices), float(t[-1]),
             len(frame_times), epsg)
    return KittiDrive(name=name, sequence=sequence, imu=oxts_to_imu(t, oxts), truth=truth, start=start,
                      utm_epsg=epsg, origin_utm=origin, convergence_rad=float(convergence[0]),
                      frame_times=frame_times, camera=camera, mosaic=find_world_mosaic(drive_dir, name),
                      path=drive_dir, first_index=indices.start,
                      t0_unix=t0_ns * 1e-9, t_unix=t_unix, oxts=oxts, _image_paths=image_paths)


def _images(drive_dir: Path, n_oxts: int, indices: range, t0_ns: int) -> tuple[np.ndarray, tuple[Path, ...]]:
    image_dir = drive_dir / "image_02"
    if not image_dir.is_dir():
        return np.zeros(0), ()
    stamps = read_timestamps(image_dir / "timestamps.txt")
    if len(stamps) != n_oxts:
        raise DataError(f"{image_dir / 'timestamps.txt'}: {len(stamps)} image timestamps but {n_oxts} OXTS "
                        "packets (a sync drive has one of each per frame)")
    n_png = count_files(image_dir / "data", ".png")
    if n_png != n_oxts:
        raise DataError(f"{image_dir / 'data'}: {n_png} PNG files but {n_oxts} frames in timestamps.txt")
    times = (stamps[indices.start:indices.stop] - t0_ns) * 1e-9
    return times, tuple(image_dir / "data" / f"{i:010d}.png" for i in indices)


def default_kitti_root() -> Path | None:
    """The KITTI raw root named by $TACO_KITTI_ROOT, else `../shared/data/kitti_raw` beside a source checkout
    (the CI layout); None when neither exists."""
    env = os.environ.get("TACO_KITTI_ROOT")
    if env:
        return Path(env) if Path(env).is_dir() else None
    beside = Path(__file__).resolve().parents[3] / "shared" / "data" / "kitti_raw"
    return beside if beside.is_dir() else None


def sequence_drive_dir(root: Path, sequence: str) -> tuple[str, Path]:
    """(normalised id, raw drive folder) of an odometry sequence id such as "05" or "5"."""
    key = str(sequence).strip()
    key = key.zfill(2) if key.isdigit() else key
    if key not in ODOMETRY_SEQUENCES:
        raise DataError(f"unknown KITTI odometry sequence {sequence!r} (known: {', '.join(ODOMETRY_SEQUENCES)})")
    seq = ODOMETRY_SEQUENCES[key]
    return key, Path(root) / seq.date / f"{seq.drive_name}_sync"


def load_sequence(root: Path, sequence: str, *, camera_height_m: float | None = None) -> KittiDrive:
    """Odometry sequence `sequence` ("00".."10") from a KITTI raw root, cut to the sequence's frames."""
    key, drive_dir = sequence_drive_dir(root, sequence)
    if not drive_dir.is_dir():
        raise DataError(f"{drive_dir}: drive folder for KITTI odometry sequence {key} not found "
                        f"(fetch it with tools/download_kitti.py {key} --root {root})")
    return load_drive(drive_dir, ODOMETRY_SEQUENCES[key].frames, sequence=key, camera_height_m=camera_height_m)
