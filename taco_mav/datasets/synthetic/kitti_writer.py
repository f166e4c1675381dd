"""Write a drive in KITTI raw layout: `<root>/<date>/<date>_drive_<nnnn>_sync/oxts/{data/*.txt, timestamps.txt,
dataformat.txt}`, `image_02/timestamps.txt` and `<root>/<date>/calib_*.txt`.

OXTS conventions (KITTI's devkit): lat/lon degrees, alt metres; roll positive = left side up, pitch positive =
front down, yaw 0 = east CCW (radians); vn, ve north/east velocity; vf, vl, vu forward/left/up velocity; ax..az
body FLU specific force including gravity (level at rest: az = +9.81); af, al, au the same in the
earth-surface-parallel frame; wx..wz body FLU rates; wf, wl, wu in the surface-parallel frame. Floats are
written with 14 significant digits, so the files are a pure function of their inputs.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from taco_mav.config import CameraConfig

__all__ = ["OXTS_FIELDS", "DATAFORMAT", "drive_dir_name", "write_oxts", "write_timestamps", "write_calib",
           "kitti_timestamps"]

OXTS_FIELDS = ("lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy wz wf wl wu "
               "pos_accuracy vel_accuracy navstat numsats posmode velmode orimode").split()

DATAFORMAT = """lat:   latitude of the oxts-unit (deg)
lon:   longitude of the oxts-unit (deg)
alt:   altitude of the oxts-unit (m)
roll:  roll angle (rad),    0 = level, positive = left side up,      range: -pi   .. +pi
pitch: pitch angle (rad),   0 = level, positive = front down,        range: -pi/2 .. +pi/2
yaw:   heading (rad),       0 = east,  positive = counter clockwise, range: -pi   .. +pi
vn:    velocity towards north (m/s)
ve:    velocity towards east (m/s)
vf:    forward velocity, i.e. parallel to earth-surface (m/s)
vl:    leftward velocity, i.e. parallel to earth-surface (m/s)
vu:    upward velocity, i.e. perpendicular to earth-surface (m/s)
ax:    acceleration in x, i.e. in direction of vehicle front (m/s^2)
ay:    acceleration in y, i.e. in direction of vehicle left (m/s^2)
az:    acceleration in z, i.e. in direction of vehicle top (m/s^2)
af:    forward acceleration (m/s^2)
al:    leftward acceleration (m/s^2)
au:    upward acceleration (m/s^2)
wx:    angular rate around x (rad/s)
wy:    angular rate around y (rad/s)
wz:    angular rate around z (rad/s)
wf:    angular rate around forward axis (rad/s)
wl:    angular rate around leftward axis (rad/s)
wu:    angular rate around upward axis (rad/s)
pos_accuracy:  velocity accuracy (north/east in m)
vel_accuracy:  velocity accuracy (north/east in m/s)
navstat:       navigation status (see navstat_to_string)
numsats:       number of satellites tracked by primary GPS receiver
posmode:       position mode of primary GPS receiver (see gps_mode_to_string)
velmode:       velocity mode of primary GPS receiver (see gps_mode_to_string)
orimode:       orientation mode of primary GPS receiver (see gps_mode_to_string)
"""

_INT_FIELDS = {"navstat", "numsats", "posmode", "velmode", "orimode"}


def drive_dir_name(date: str, drive: int) -> str:
    """KITTI drive folder name, e.g. ('2011_01_01', 1) -> '2011_01_01_drive_0001_sync'."""
    return f"{date}_drive_{drive:04d}_sync"


def kitti_timestamps(start: _dt.datetime, t: np.ndarray) -> list[str]:
    """KITTI timestamp strings 'YYYY-MM-DD HH:MM:SS.nnnnnnnnn' for offsets `t` seconds after `start`."""
    base_ns = int(round(start.replace(tzinfo=_dt.timezone.utc).timestamp())) * 1_000_000_000
    out = []
    for ns in (base_ns + np.round(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64)).tolist():
        sec, frac = divmod(int(ns), 1_000_000_000)
        stamp = _dt.datetime.fromtimestamp(sec, tz=_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
        out.append(f"{stamp}.{frac:09d}")
    return out


def write_timestamps(path: Path, stamps: list[str]) -> None:
    """One KITTI timestamp per line."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(s + "\n" for s in stamps))


def write_oxts(oxts_dir: Path, values: np.ndarray, stamps: list[str]) -> None:
    """Write oxts/data/%010d.txt (one line of the 30 fields per sample), timestamps.txt and dataformat.txt.
    values: (N, 30) in OXTS_FIELDS order."""
    if values.ndim != 2 or values.shape[1] != len(OXTS_FIELDS) or len(values) != len(stamps):
        raise ValueError(f"OXTS values must be (N, {len(OXTS_FIELDS)}) with N timestamps, got {values.shape}")
    data = oxts_dir / "data"
    data.mkdir(parents=True, exist_ok=True)
    fmt = " ".join("%d" if f in _INT_FIELDS else "%.14g" for f in OXTS_FIELDS) + "\n"
    for i, row in enumerate(values):
        vals = tuple(int(v) if f in _INT_FIELDS else float(v) for f, v in zip(OXTS_FIELDS, row))
        (data / f"{i:010d}.txt").write_text(fmt % vals)
    write_timestamps(oxts_dir / "timestamps.txt", stamps)
    (oxts_dir / "dataformat.txt").write_text(DATAFORMAT)


def _row(name: str, values) -> str:
    return f"{name}: " + " ".join(f"{float(v):.6e}" for v in np.ravel(values)) + "\n"


def write_calib(date_dir: Path, cam: CameraConfig) -> None:
    """calib_cam_to_cam.txt (rectified, distortion-free cameras 00 and 02 with `cam`'s intrinsics),
    calib_velo_to_cam.txt and calib_imu_to_velo.txt (the camera sits on the IMU, axes permuted FLU -> RDF)."""
    date_dir.mkdir(parents=True, exist_ok=True)
    P = np.array([[cam.fx, 0.0, cam.cx, 0.0], [0.0, cam.fy, cam.cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    K = P[:, :3]
    lines = ["calib_time: 01-Jan-2011 00:00:00\n", _row("corner_dist", [0.0])]
    for k in ("00", "02"):
        lines += [_row(f"S_{k}", [cam.width_px, cam.height_px]), _row(f"K_{k}", K), _row(f"D_{k}", np.zeros(5)),
                  _row(f"R_{k}", np.eye(3)), _row(f"T_{k}", np.zeros(3)),
                  _row(f"S_rect_{k}", [cam.width_px, cam.height_px]), _row(f"R_rect_{k}", np.eye(3)),
                  _row(f"P_rect_{k}", P)]
    (date_dir / "calib_cam_to_cam.txt").write_text("".join(lines))
    c, s = np.cos(cam.pitch_rad), np.sin(cam.pitch_rad)
    # velodyne (x fwd, y left, z up) -> camera (x right, y down, z fwd), pitched down by pitch_rad
    R = np.array([[0.0, -1.0, 0.0], [-s, 0.0, -c], [c, 0.0, -s]])
    (date_dir / "calib_velo_to_cam.txt").write_text(
        "calib_time: 01-Jan-2011 00:00:00\n" + _row("R", R) + _row("T", np.zeros(3))
        + _row("delta_f", [0.0, 0.0]) + _row("delta_c", [0.0, 0.0]))
    (date_dir / "calib_imu_to_velo.txt").write_text(
        "calib_time: 01-Jan-2011 00:00:00\n" + _row("R", np.eye(3)) + _row("T", [0.0, 0.0, cam.mount_height_m]))
