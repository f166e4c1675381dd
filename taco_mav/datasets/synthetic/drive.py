"""`load_world`: a synthetic world folder as a `Drive` whose camera frames are rendered on demand.

The IMU, start fix and UTM zone come from the KITTI reader (`taco_mav.datasets.kitti.load_drive`) over the
world's OXTS, exactly as for a real drive; ground truth is the generator's exact truth (`truth.npz`: UTM
metres, headings on the UTM grid), not the OXTS fields (which carry the noisy attitude). Frame i is rendered
from the mosaic at the TRUE camera pose at `frame_times[i]` (seconds from the first IMU sample).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig
from taco_mav.datasets.base import GroundTruth, ImuStream, StartFix, WheelLog
from taco_mav.datasets.kitti import KittiDrive, load_drive
from taco_mav.datasets.synthetic.render import GroundRenderer
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["SyntheticDrive", "load_world", "read_world_json"]


def read_world_json(world_dir: Path) -> dict[str, Any]:
    """The world's metadata (world.json), DataError when missing or malformed."""
    path = Path(world_dir) / "world.json"
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"{path}: not found (is {world_dir} a world made by `taco-mav world`?)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not readable JSON ({exc})") from None
    for key in ("mosaic", "drive", "truth", "crs_epsg"):
        if key not in meta:
            raise DataError(f"{path}: key {key!r} missing")
    return meta


@dataclass(eq=False)
class SyntheticDrive:
    """A synthetic world's drive behind the `Drive` protocol (units in datasets/base.py), plus `world_dir`,
    `meta` (world.json), `kitti` (the underlying KittiDrive) and `truth_utm` (N, 2) absolute UTM metres."""

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
    world_dir: Path
    meta: dict[str, Any]
    kitti: KittiDrive
    truth_utm: np.ndarray
    _renderer: Any = field(default=None, repr=False)
    wheels: WheelLog | None = None  # a world's drive has no wheel encoders

    def camera_pose(self, t: float) -> tuple[float, float, float]:
        """True camera pose at time t: (E, N) absolute UTM metres and heading on the UTM grid, ENU radians."""
        x, y, th = self.truth.pose_at(t)
        return float(self.origin_utm[0] + x), float(self.origin_utm[1] + y), th

    def renderer(self) -> Any:
        """The camera renderer (built on first use): a `GroundRenderer` over the mosaic for flat worlds, a
        `world3d.WorldRenderer3D` (perspective, occlusion, the camera's own day) for 3d worlds."""
        if self._renderer is None:
            if self.camera is None or self.mosaic is None:
                raise DataError(f"{self.world_dir}: world has no camera or no mosaic")
            if self.meta.get("realism") == "3d":
                from taco_mav.datasets.synthetic.world3d import WorldRenderer3D

                self._renderer = WorldRenderer3D(self.world_dir, self.camera, self.meta)
                return self._renderer
            with rasterio.open(self.mosaic) as src:
                img = np.ascontiguousarray(src.read().transpose(1, 2, 0))
                transform = src.transform
            if img.shape[2] != 3:
                raise DataError(f"{self.mosaic}: expected 3 bands (RGB), found {img.shape[2]}")
            self._renderer = GroundRenderer(img, transform, self.camera)
        return self._renderer

    def frame(self, index: int) -> np.ndarray:
        """Camera frame `index` rendered at the true pose, uint8 RGB (H, W, 3)."""
        if not 0 <= index < len(self.frame_times):
            raise DataError(f"{self.world_dir}: frame {index} out of range (world has {len(self.frame_times)} frames)")
        t = float(self.frame_times[index])
        if self.meta.get("realism") == "3d":
            return self.renderer().render(self.camera_pose(t), t)  # t: where the moving cars are
        return self.renderer().render(self.camera_pose(t))


def load_world(world_dir: Path) -> SyntheticDrive:
    """Open a world folder written by `build_world` (DataError naming the file when something is missing)."""
    world_dir = Path(world_dir)
    meta = read_world_json(world_dir)
    kd = load_drive(world_dir / meta["drive"])
    truth_path = world_dir / meta["truth"]
    try:
        with np.load(truth_path) as z:
            t, utm, heading, frame_t = z["t"], z["utm"], z["heading"], z["frame_t"]
    except FileNotFoundError:
        raise DataError(f"{truth_path}: exact truth file not found") from None
    except (KeyError, ValueError, OSError) as exc:
        raise DataError(f"{truth_path}: not a truth file ({exc})") from None
    if len(t) != len(kd.imu):
        raise DataError(f"{truth_path}: {len(t)} truth samples but {len(kd.imu)} OXTS packets")
    origin = utm[0].copy()
    if np.linalg.norm(origin - kd.origin_utm) > 0.01:
        raise DataError(f"{truth_path}: truth origin {origin} disagrees with the OXTS start fix {kd.origin_utm}")
    cam = kd.camera or GroundCamera.from_config(CameraConfig(**meta.get("camera", {})))
    return SyntheticDrive(
        name=kd.name, sequence=None, imu=kd.imu, truth=GroundTruth(t, utm - origin, heading), start=kd.start,
        utm_epsg=kd.utm_epsg, origin_utm=origin, frame_times=np.asarray(frame_t, dtype=np.float64), camera=cam,
        mosaic=(world_dir / meta["mosaic"]).resolve(), world_dir=world_dir, meta=meta, kitti=kd, truth_utm=utm)
