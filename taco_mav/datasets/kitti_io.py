"""Strict readers for KITTI raw files: timestamps.txt, oxts/data/*.txt, calib_*.txt, world.json; the camera's
lever arm from the calibration chain (`camera_position_frd_m`).

Each reader refuses what it cannot read with a DataError naming the file and, where there is one, the
1-based line number; nothing is silently truncated or skipped. Units are KITTI's own (see `OXTS_FIELDS`).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from taco_mav.errors import DataError
from taco_mav.timestamps import read_timestamps  # noqa: F401 - re-exported: the KITTI readers' timestamp parser

log = logging.getLogger(__name__)

# The 30 OXTS fields per line, in order (oxts/dataformat.txt). Angles rad, rates rad/s, accelerations m/s^2
# (ax..az: body FLU specific force, gravity included), velocities m/s, lat/lon degrees, alt metres.
OXTS_FIELDS: tuple[str, ...] = (
    "lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az",
    "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy",
    "navstat", "numsats", "posmode", "velmode", "orimode",
)
OXTS: dict[str, int] = {name: i for i, name in enumerate(OXTS_FIELDS)}
_N_OXTS = len(OXTS_FIELDS)


def read_oxts(data_dir: Path, indices: Sequence[int]) -> np.ndarray:
    """OXTS packets `data_dir/<index:010d>.txt` for `indices` -> (len(indices), 30) float64, `OXTS_FIELDS`
    order. Each file must hold exactly one line of 30 numbers; the navigation fields must be finite."""
    chunks: list[list[bytes]] = []
    for index in indices:
        path = data_dir / f"{index:010d}.txt"
        try:
            with open(path, "rb") as fh:
                content = fh.read()
        except FileNotFoundError:
            raise DataError(f"{path}: OXTS packet file not found") from None
        except OSError as exc:
            raise DataError(f"{path}: cannot read ({exc.strerror})") from None
        parts = content.split()
        if len(parts) != _N_OXTS or content.strip().count(b"\n"):
            _raise_bad_shape(path, content)
        chunks.append(parts)
    try:
        values = np.array(chunks, dtype=np.float64).reshape(len(chunks), _N_OXTS)
    except ValueError:
        for index, parts in zip(indices, chunks):
            for k, word in enumerate(parts):
                try:
                    float(word)
                except ValueError:
                    raise DataError(f"{data_dir / f'{index:010d}.txt'}, line 1: field {k + 1} ({OXTS_FIELDS[k]}) "
                                    f"is not a number: {word.decode(errors='replace')!r}") from None
        raise  # pragma: no cover - numpy refused something float() accepts
    nav = values[:, : OXTS["wu"] + 1]
    bad_rows = np.flatnonzero(~np.all(np.isfinite(nav), axis=1))
    if len(bad_rows):
        row = int(bad_rows[0])
        raise DataError(f"{data_dir / f'{indices[row]:010d}.txt'}, line 1: non-finite navigation value")
    return values


def _raise_bad_shape(path: Path, content: bytes) -> None:
    lines = content.decode(errors="replace").splitlines()
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        n = len(line.split())
        if n != _N_OXTS:
            raise DataError(f"{path}, line {number}: expected {_N_OXTS} OXTS fields, found {n}")
        if number > 1 or any(other.strip() for other in lines[number:]):
            raise DataError(f"{path}, line {number + 1}: expected one OXTS line per file, found more")
    raise DataError(f"{path}, line 1: empty OXTS packet (expected {_N_OXTS} fields)")


def count_files(folder: Path, suffix: str) -> int:
    """Number of plain files named `*<suffix>` in `folder` (DataError when the folder is missing)."""
    try:
        return sum(1 for e in os.scandir(folder) if e.name.endswith(suffix) and e.is_file())
    except FileNotFoundError:
        raise DataError(f"{folder}: folder not found") from None


def read_calib(path: Path) -> dict[str, str]:
    """A KITTI calibration file (`KEY: values` per line) -> {key: raw value string}."""
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from None
    out: dict[str, str] = {}
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        key, sep, value = line.partition(":")
        if not sep or not key.strip():
            raise DataError(f"{path}, line {number}: expected 'KEY: values', got {line.strip()[:60]!r}")
        out[key.strip()] = value.strip()
    return out


def calib_numbers(calib: dict[str, str], key: str, count: int, path: Path) -> np.ndarray:
    """The `count` numbers of calibration entry `key` as float64 (DataError naming the file and key)."""
    if key not in calib:
        raise DataError(f"{path}: key {key} missing")
    try:
        values = np.array([float(v) for v in calib[key].split()])
    except ValueError:
        raise DataError(f"{path}: key {key}: not all values are numbers") from None
    if len(values) != count or not np.all(np.isfinite(values)):
        raise DataError(f"{path}: key {key}: expected {count} finite numbers, found {len(values)}")
    return values


def _rigid(folder: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), T (3,)) of a KITTI rigid calibration file (x_to = R x_from + T, metres)."""
    path = folder / name
    calib = read_calib(path)
    return calib_numbers(calib, "R", 9, path).reshape(3, 3), calib_numbers(calib, "T", 3, path)


def camera_position_frd_m(calib_dir: Path, camera: str = "02") -> np.ndarray:
    """The rectified camera `camera`'s optical centre in the OXTS/IMU frame, body FRD metres, shape (3,): the
    profile's camera.position_frd_m (lever arm) for KITTI, from the date folder's own calibration.

    Chain (KITTI raw devkit): x_velo = R x_imu + T (calib_imu_to_velo.txt), x_cam0 = R x_velo + T
    (calib_velo_to_cam.txt), x_rect0 = R_rect_00 x_cam0 and image = P_rect_<camera> [x_rect0; 1]
    (calib_cam_to_cam.txt). The camera centre C solves P [C; 1] = 0: C = -P[:, :3]^-1 P[:, 3] in rectified
    cam-0 coordinates; it is carried back to the IMU frame, which KITTI gives as FLU (x forward, y left, z up),
    and returned as FRD [x, -y, -z]. 2011_09_26, image_02: FLU [1.080, -0.250, 0.729]."""
    R_iv, T_iv = _rigid(calib_dir, "calib_imu_to_velo.txt")
    R_vc, T_vc = _rigid(calib_dir, "calib_velo_to_cam.txt")
    path = calib_dir / "calib_cam_to_cam.txt"
    calib = read_calib(path)
    R_rect = calib_numbers(calib, "R_rect_00", 9, path).reshape(3, 3)
    P = calib_numbers(calib, f"P_rect_{camera}", 12, path).reshape(3, 4)
    try:
        centre_rect0 = -np.linalg.solve(P[:, :3], P[:, 3])
    except np.linalg.LinAlgError:
        raise DataError(f"{path}: P_rect_{camera} is singular: not a camera") from None
    x_cam0 = R_rect.T @ centre_rect0
    x_velo = R_vc.T @ (x_cam0 - T_vc)
    flu = R_iv.T @ (x_velo - T_iv)
    return np.array([flu[0], -flu[1], -flu[2]])


def _names_drive(value: Any, drive_name: str) -> bool:
    tail = Path(str(value)).name
    return tail.removesuffix("_sync") == drive_name.removesuffix("_sync")


def find_world_mosaic(drive_dir: Path, drive_name: str) -> Path | None:
    """The satellite GeoTIFF of a synthetic world holding this drive, or None.

    Looks for `world.json` in the drive folder, its date folder, then the dataset root (nearest first). Its
    `"mosaic"` is a path relative to the world.json's folder (absolute paths are taken as they are); an
    optional `"drive"` (a drive name or a path to the drive folder) restricts it to that drive. Other keys are
    ignored. A world.json that is not a JSON object, lacks "mosaic" or names a missing file is refused.
    """
    for folder in (drive_dir, drive_dir.parent, drive_dir.parent.parent):
        world = folder / "world.json"
        if not world.is_file():
            continue
        try:
            data = json.loads(world.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"{world}: not readable JSON ({exc})") from None
        if not isinstance(data, dict):
            raise DataError(f"{world}: expected a JSON object at the top level")
        if "drive" in data and not _names_drive(data["drive"], drive_name):
            log.info("%s describes drive %r, not %s: no mosaic taken from it", world, data["drive"], drive_name)
            continue
        if not isinstance(data.get("mosaic"), str) or not data["mosaic"]:
            raise DataError(f"{world}: key \"mosaic\" (a GeoTIFF path relative to this file) missing or not a string")
        mosaic = (folder / data["mosaic"]).resolve()
        if not mosaic.is_file():
            raise DataError(f"{world}: mosaic {data['mosaic']!r} not found (looked at {mosaic})")
        log.debug("%s: mosaic %s from %s", drive_name, mosaic, world)
        return mosaic
    return None
