"""A drive recorded by the daemon (`taco-mav run --log-dir DIR --record`): the session's mav.tlog for
the IMU, attitude and the real receiver's fixes (the ground truth, never fused: `datasets.tlog`), and its
frames/ folder for the camera (frames.csv: each JPEG's capture time on the autopilot clock, the IMU's clock).
`taco-mav eval --tlog SESSION/mav.tlog --frames SESSION/frames --map MAP.tif` runs the pipeline the daemon runs
on it (the same Localiser, matcher and camera speed) and scores it against the receiver.

Frames and units as `datasets.base`: ENU metres from the first receiver fix on its UTM grid; autopilot seconds.
The camera is the profile's (`GroundCamera.from_config`), as in the daemon that recorded it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from taco_mav.camera.sources import FolderSource
from taco_mav.datasets.tlog import TlogDrive, load_tlog
from taco_mav.errors import DataError

__all__ = ["load_recording"]


def load_recording(tlog: Path, frames: Path, mosaic: Path | None = None,
                   imu_message: str | None = None) -> TlogDrive:
    """The session's tlog with its recorded frames and the map they are matched on (DataError naming the file at
    fault). Frames outside the tlog's IMU span are dropped; at least two must remain."""
    drive = load_tlog(Path(tlog), imu_message)
    src = FolderSource(Path(frames))
    times = np.array(src.times)
    inside = (times >= drive.imu.t[0]) & (times <= drive.imu.t[-1])
    if inside.sum() < 2:
        raise DataError(f"{frames}: {len(times)} frames, {int(inside.sum())} within the tlog's IMU span "
                        f"{drive.imu.t[0]:.1f}-{drive.imu.t[-1]:.1f} s (autopilot time): not this session's frames?")
    if mosaic is not None and not Path(mosaic).is_file():
        raise DataError(f"{mosaic}: map not found")
    return dataclasses.replace(drive, name=Path(tlog).resolve().parent.name or Path(tlog).stem,
                               frame_times=times[inside], frame_paths=tuple(p for p, k in zip(src.paths, inside) if k),
                               mosaic=Path(mosaic) if mosaic is not None else None)
