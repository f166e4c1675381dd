"""The `--camera world:DIR[?faults=FILE]` source: renders a synthetic world (flat or 3-D) at the simulator's true
pose (SIMSTATE), for simulation only; FILE puts camera faults on cue (world_faults.py).

It lives here, beside the renderers it draws with, and not in `taco_mav.camera.sources`: the camera layer (and the
daemon's link layer above it) never imports datasets. `taco_mav.camera.sources.open_camera` finds the `world:` scheme in
its registry, which `register_world_camera` fills; importing `taco_mav.datasets.synthetic` registers it, and the
top layer (CLI commands, demo) does so before it starts a daemon.
"""

from __future__ import annotations

import json
import math
import threading
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from taco_mav.camera.calibration import LensCalibration
from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.sources import ClockDomain, register_camera_scheme
from taco_mav.datasets.synthetic.world_faults import CameraFaults
from taco_mav.errors import ConfigError

if TYPE_CHECKING:
    from taco_mav.datasets.synthetic.render import GroundRenderer, LensRenderer
    from taco_mav.datasets.synthetic.world3d import LensRenderer3D, WorldRenderer3D

__all__ = ["WORLD_SCHEME", "WorldSource", "register_world_camera", "world_mosaic"]

WORLD_SCHEME = "world"


def world_mosaic(world_dir: Path) -> Path:
    """The GeoTIFF named by DIR/world.json ("mosaic", relative to DIR)."""
    meta = Path(world_dir) / "world.json"
    try:
        data = json.loads(meta.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"--camera world:{world_dir}: cannot read world.json ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("mosaic"), str):
        raise ConfigError(f"{meta}: key \"mosaic\" missing")
    path = (Path(world_dir) / data["mosaic"]).resolve()
    if not path.is_file():
        raise ConfigError(f"{meta}: mosaic {path} not found")
    return path


class WorldSource:
    """Renders the synthetic world's ground view at the simulator's true pose (simulation only). Poses come in
    through `feed_pose` (autopilot time s, lat/lon degrees, NED yaw rad, true north); a frame is rendered only
    when asked for, at the stored pose nearest the requested time. With `lens` the frames are drawn through it
    (its size and distortion; `camera` gives the mount height and pitch), as a real calibrated camera's.
    `mosaic_path`: the world's GeoTIFF, the daemon's satellite map when no `--map` is given."""

    clock = ClockDomain.AUTOPILOT
    needs_pose = True
    noiseless = True

    def __init__(self, world_dir: str | Path, camera: GroundCamera, ring: int = 2000,
                 lens: LensCalibration | None = None, faults: str | Path | None = None) -> None:
        import rasterio

        from taco_mav.datasets.synthetic.render import GroundRenderer, LensRenderer
        from taco_mav.datasets.synthetic.world3d import LensRenderer3D, WorldRenderer3D, world_is_3d
        from taco_mav.geo import UtmProjector

        self.mosaic_path: Path | None = world_mosaic(Path(world_dir))
        with rasterio.open(self.mosaic_path) as ds:
            bands = ds.read()
            transform, epsg = ds.transform, ds.crs.to_epsg()
        rgb = np.repeat(bands[:1], 3, axis=0) if bands.shape[0] < 3 else bands[:3]
        mosaic = np.ascontiguousarray(np.transpose(rgb, (1, 2, 0)))
        self.is_3d = world_is_3d(Path(world_dir))
        self._t0: float | None = None  # autopilot time of the first pose = drive time 0 (moving cars)
        self.renderer: GroundRenderer | LensRenderer | WorldRenderer3D | LensRenderer3D
        if self.is_3d:  # perspective, occlusion, the camera's own day (datasets/synthetic/world3d.py)
            self.renderer = (WorldRenderer3D(Path(world_dir), camera) if lens is None else
                             LensRenderer3D(Path(world_dir), lens, camera.mount_height_m, camera.pitch_rad))
        else:
            self.renderer = (
                GroundRenderer(mosaic, transform, camera) if lens is None
                else LensRenderer(mosaic, transform, lens, camera.mount_height_m, camera.pitch_rad))
        self._size = (camera.width, camera.height) if lens is None else (lens.width, lens.height)
        self.projector = UtmProjector(int(epsg))
        self._poses: deque[tuple[float, float, float, float]] = deque(maxlen=ring)
        self._lock = threading.Lock()
        self.faults = None if faults is None else CameraFaults(faults)  # on cue, for closed-loop tests
        self.noiseless = faults is None  # with faults, a real sensor's noise (world_faults.py)

    def feed_pose(self, t: float, lat: float, lon: float, yaw_ned: float) -> None:
        e, n = self.projector.to_utm(lat, lon)
        theta = math.pi / 2.0 - yaw_ned + float(self.projector.grid_convergence(lat, lon))
        with self._lock:
            if self._poses and t < self._poses[-1][0]:
                self._poses.clear()  # the autopilot clock went back (reboot)
                self._t0 = None
            if self._t0 is None:
                self._t0 = t
            self._poses.append((t, float(e), float(n), math.remainder(theta, 2 * math.pi)))

    def frame_size(self) -> tuple[int, int] | None:
        return self._size

    def start(self) -> None:
        pass

    def frame_near(self, t: float, max_gap_s: float, grey: bool = False) -> tuple[float, np.ndarray] | None:
        with self._lock:
            if not self._poses:
                return None
            best = min(self._poses, key=lambda p: abs(p[0] - t))
        if abs(best[0] - t) > max_gap_s:
            return None
        if self.is_3d:
            frame = self.renderer.render(np.array(best[1:]), best[0] - (self._t0 or 0.0))
        else:
            frame = self.renderer.render(np.array(best[1:]))
        got = (best[0], frame) if self.faults is None else self.faults.apply(best[0], frame)
        return got if not grey or got is None else (got[0], cv2.cvtColor(got[1], cv2.COLOR_RGB2GRAY))

    def close(self) -> None:
        if self.is_3d:
            self.renderer.close()  # the GL context and its thread


def _open_world(body: str, camera: GroundCamera, lens: LensCalibration | None) -> WorldSource:
    """`world:DIR` or `world:DIR?faults=FILE` (camera faults on cue, world_faults.py)."""
    world, sep, query = body.partition("?")
    if not sep:
        return WorldSource(world, camera, lens=lens)
    key, eq, value = query.partition("=")
    if key != "faults" or not eq or not value:
        raise ConfigError(f"--camera world:{body}: after '?' only faults=FILE is known")
    return WorldSource(world, camera, lens=lens, faults=value)


def register_world_camera() -> None:
    """Make `open_camera("world:DIR", ...)` return a `WorldSource` (idempotent)."""
    register_camera_scheme(WORLD_SCHEME, _open_world)
