"""The dataset protocol: what every data source yields, in the units an autopilot reports.

Frames and units: IMU in body FRD (specific force m/s^2 including gravity; gyro rad/s); attitude roll, pitch,
yaw radians NED (yaw 0 = north, CW). Ground truth and the origin in UTM metres; `xy` arrays are ENU metres
relative to the origin (the single start-up GNSS reading, frame 0). Images are uint8 RGB, shape (H, W, 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.core.types import ImuSample


@dataclass(frozen=True)
class ImuStream:
    """A timed IMU stream. t: (N,) s; accel_frd, gyro_frd: (N, 3); rpy_ned: (N, 3) roll, pitch, yaw rad."""

    t: np.ndarray
    accel_frd: np.ndarray
    gyro_frd: np.ndarray
    rpy_ned: np.ndarray

    def __len__(self) -> int:
        return len(self.t)

    def samples(self) -> Iterator[ImuSample]:
        """The stream as ImuSample objects, in time order."""
        for i in range(len(self.t)):
            a, g, r = self.accel_frd[i], self.gyro_frd[i], self.rpy_ned[i]
            yield ImuSample(float(self.t[i]), (float(a[0]), float(a[1]), float(a[2])),
                            (float(g[0]), float(g[1]), float(g[2])), float(r[0]), float(r[1]), float(r[2]))


@dataclass(frozen=True)
class StartFix:
    """The single start-up GNSS reading. lat/lon degrees WGS84, alt metres; speed m/s over ground;
    course ENU radians (0 = east, CCW); t seconds on the dataset clock."""

    t: float
    lat: float
    lon: float
    alt: float
    speed: float
    course: float


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth. t: (M,) s; xy: (M, 2) ENU metres relative to the origin; heading: (M,) ENU radians."""

    t: np.ndarray
    xy: np.ndarray
    heading: np.ndarray

    def length_m(self) -> float:
        """Path length, metres."""
        return float(np.linalg.norm(np.diff(self.xy, axis=0), axis=1).sum()) if len(self.xy) > 1 else 0.0

    def pose_at(self, t: float) -> tuple[float, float, float]:
        """Interpolated (x, y, heading) at time t (ENU metres relative to the origin, radians)."""
        x = float(np.interp(t, self.t, self.xy[:, 0]))
        y = float(np.interp(t, self.t, self.xy[:, 1]))
        unwrapped = np.unwrap(self.heading)
        th = float(np.interp(t, self.t, unwrapped))
        return x, y, float(np.arctan2(np.sin(th), np.cos(th)))


@dataclass(frozen=True)
class WheelLog:
    """Wheel-encoder samples as the autopilot sent them (WHEEL_DISTANCE): t (N,) autopilot s, increasing;
    distances (N, W) cumulative metres per wheel; pos_y_m: the wheels' lateral positions the autopilot reported
    (WENC_POS_Y, WENC2_POS_Y: body FRD metres) when the recording holds them, else None."""

    t: np.ndarray
    distances: np.ndarray
    pos_y_m: tuple[float, float] | None = None


class Drive(Protocol):
    """One drive from any source.

    name: e.g. "2011_09_30_drive_0018" (sequence: odometry id like "05", or None). utm_epsg: EPSG code of the
    UTM zone; origin_utm: (2,) UTM easting/northing of the start fix, metres. frame_times: (F,) s, empty when
    the drive has no images. camera: the camera's flat-ground model, or None without images. mosaic: path of a
    satellite GeoTIFF covering the drive (synthetic worlds), or None. wheels: the wheel encoders' samples (a
    recording's WHEEL_DISTANCE), or None.
    """

    name: str
    sequence: str | None
    imu: ImuStream
    truth: GroundTruth
    start: StartFix
    utm_epsg: int
    origin_utm: np.ndarray
    frame_times: np.ndarray
    camera: GroundCamera | None
    mosaic: Path | None
    wheels: WheelLog | None

    def frame(self, index: int) -> np.ndarray:
        """Camera frame `index` as uint8 RGB (H, W, 3); raises DataError when the drive has no images."""
        ...
