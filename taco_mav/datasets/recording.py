"""A drive recorded by the daemon (`taco-mav run --log-dir DIR --record`, issue 30): the session's mav.tlog for
the IMU, attitude and the real receiver's fixes (the ground truth, never fused: `datasets.tlog`), and its
frames/ folder for the camera (frames.csv: each JPEG's capture time on the autopilot clock, the IMU's clock).
`taco-mav eval --tlog SESSION/mav.tlog --frames SESSION/frames --map MAP.tif` runs the pipeline the daemon runs
on it (the same Localiser, matcher and camera speed) and scores it against the receiver.

Frames and units as `datasets.base`: ENU metres from the first receiver fix on its UTM grid; autopilot seconds.
The camera is the profile's (`GroundCamera.from_config`), as in the daemon that recorded it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.sources import FolderSource
from taco_mav.datasets.base import GroundTruth, ImuStream, StartFix
from taco_mav.datasets.tlog import load_tlog
from taco_mav.errors import DataError

__all__ = ["RecordedDrive", "load_recording"]


@dataclass(frozen=True)
class RecordedDrive:
    """A Drive (datasets.base) from a recorded session: the tlog's IMU and receiver, the recorded frames (paths:
    one JPEG per entry of frame_times, autopilot s), the map the daemon matched against."""

    name: str
    imu: ImuStream
    truth: GroundTruth
    start: StartFix
    utm_epsg: int
    origin_utm: np.ndarray
    convergence_rad: float
    frame_times: np.ndarray
    paths: tuple[Path, ...]
    mosaic: Path | None
    receiver: str = "GPS_RAW_INT"
    rejected: dict[str, int] = field(default_factory=dict)
    sequence: str | None = None
    camera: GroundCamera | None = None

    def frame(self, index: int) -> np.ndarray:
        """Frame `index` as RGB uint8 (H, W, 3); DataError naming the file when it cannot be read."""
        bgr = cv2.imread(str(self.paths[index]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise DataError(f"{self.paths[index]}: recorded frame not readable")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def load_recording(tlog: Path, frames: Path, mosaic: Path | None = None,
                   imu_message: str | None = None) -> RecordedDrive:
    """The session's tlog and frames folder as a drive (DataError naming the file at fault). Frames outside the
    tlog's IMU span are dropped; at least two must remain."""
    drive = load_tlog(Path(tlog), imu_message)
    src = FolderSource(Path(frames))
    times = np.array(src.times)
    inside = (times >= drive.imu.t[0]) & (times <= drive.imu.t[-1])
    if inside.sum() < 2:
        raise DataError(f"{frames}: {len(times)} frames, {int(inside.sum())} within the tlog's IMU span "
                        f"{drive.imu.t[0]:.1f}-{drive.imu.t[-1]:.1f} s (autopilot time): not this session's frames?")
    if mosaic is not None and not Path(mosaic).is_file():
        raise DataError(f"{mosaic}: map not found")
    name = Path(tlog).resolve().parent.name or Path(tlog).stem
    return RecordedDrive(name=name, imu=drive.imu, truth=drive.truth, start=drive.start, utm_epsg=drive.utm_epsg,
                         origin_utm=drive.origin_utm, convergence_rad=drive.convergence_rad,
                         frame_times=times[inside], paths=tuple(p for p, k in zip(src.paths, inside) if k),
                         mosaic=Path(mosaic) if mosaic is not None else None, receiver=drive.receiver,
                         rejected=drive.rejected)
