"""The 3-D layer of a synthetic world (`--realism 3d`): ground texture, 3-D scene, aerial orthophoto, renderers.

`build_world3d` runs after the layout (`layout.py`) inside `build_world` and writes, beside the drive:
  ground.tif       the ground as the camera sees it (no roofs, canopies, cars or shadows: those are 3-D now),
                   RGB uint8 GeoTIFF, 0.1 m/px (coarser only for worlds wider than 800 m), same texture model as
                   the flat mosaic; ground_mat.tif: its material labels (`mosaic.Material`), for the season tint
  scene3d.npz      the meshes (`scene3d.Scene3D.to_npz`): static buildings/trees/poles, parked cars per epoch
                   (camera, aerial), moving cars
  mosaic.tif       the satellite map: the scene rendered from straight above (`render3d`) on ANOTHER day: its
                   own sun (azimuth 190-240 deg, elevation 28-40 deg, shadows cast by the 3-D objects), season
                   (autumn tint of grass and leaves), parked cars partly moved, moving cars elsewhere; at
                   0.3 m/px (rendered at 0.15 m/px and area-averaged), lightly blurred, with sensor noise and JPEG
                   compression; raised points lean 0.02-0.06 m per metre of height in a seeded direction (an
                   orthophoto that is not a true ortho: roofs off their footprints, one side of the facades
                   seen); and a georeferencing error: a seeded offset of about 1 m in a random direction
                   (world.json "aerial" / "georef_offset_m"): a feature at true local (x, y) appears in the
                   GeoTIFF at (x + dx, y + dy). The drive, IMU and truth are unaffected.
The camera's day (world.json "camera_light"): sun azimuth 120-170 deg, elevation 45-60 deg, summer.

`WorldRenderer3D` renders camera frames of such a world at UTM poses (what `load_world(...).frame(i)` and
`--camera world:DIR` use for 3d worlds).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import Affine

from taco_mav.camera.geometry import GroundCamera
from taco_mav.datasets.synthetic import paint
from taco_mav.datasets.synthetic.layout import Scene
from taco_mav.datasets.synthetic.mosaic import Canvas, Material, write_geotiff
from taco_mav.datasets.synthetic.render3d import GlRenderer3D, Lighting
from taco_mav.datasets.synthetic.scene3d import Scene3D, build_scene3d
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["build_world3d", "WorldRenderer3D", "AERIAL_M_PER_PX", "REALISMS"]

REALISMS = ("flat", "3d")
AERIAL_M_PER_PX = 0.3
GROUND_M_PER_PX = 0.1
AERIAL_SUPERSAMPLE = 2
TILE_PX = 1024
GEOREF_ERROR_M = 1.0
LEAN = (0.02, 0.06)  # relief displacement of the aerial: metres per metre of height (a 20 m roof: 0.4-1.2 m)


def _lot_ground(cv: Canvas, scene: Scene) -> None:
    """Parking lots: asphalt and bay lines (the cars are 3-D objects)."""
    for lot in scene.lots:
        c = lot.corners
        u, v, L, bands = paint.lot_axes(cv, lot)
        lines = [np.array([c[0] + u * (k * 2.5 + 0.2) + v * v0, c[0] + u * (k * 2.5 + 0.2) + v * v1])
                 for v0, v1 in bands for k in range(int(L / 2.5) + 1)]
        cv.line(lines, 0.15, paint.WHITE, Material.MARKING)


def _paint_ground(scene: Scene, x0: float, y1: float, w: int, h: int, res: float, rng: np.random.Generator) -> Canvas:
    cv = Canvas.blank(x0, y1, w, h, res)
    paint._ground(cv, scene)
    _lot_ground(cv, scene)
    paint._roads(cv, scene)
    paint._wear(cv, scene, rng)
    paint._junction_patterns(cv, scene)
    paint._markings(cv, scene)
    return cv


def _write_rgb(path: Path, img: np.ndarray, transform: Affine, epsg: int) -> None:
    profile = dict(driver="GTiff", width=img.shape[1], height=img.shape[0], count=img.shape[2] if img.ndim == 3 else 1,
                   dtype="uint8", crs=CRS.from_epsg(epsg), transform=transform, compress="deflate", predictor=2,
                   tiled=True, blockxsize=512, blockysize=512)
    if img.ndim == 3:
        profile.update(photometric="RGB", interleave="pixel")
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path, "w", **profile) as dst:
        dst.write(img.transpose(2, 0, 1) if img.ndim == 3 else img[None])


def _read_rgb(path: Path) -> tuple[np.ndarray, Affine]:
    with rasterio.open(path) as src:
        return np.ascontiguousarray(src.read().transpose(1, 2, 0)), src.transform


def lightings(rng: np.random.Generator) -> tuple[Lighting, Lighting]:
    """(camera day, aerial day) drawn from `rng` (see the module docstring)."""
    cam = Lighting(sun_az_deg=float(rng.uniform(120, 170)), sun_elev_deg=float(rng.uniform(45, 60)), season=0.0)
    aer = Lighting(sun_az_deg=float(rng.uniform(190, 240)), sun_elev_deg=float(rng.uniform(28, 40)),
                   season=float(rng.uniform(0.5, 0.9)), exposure=float(rng.uniform(0.9, 1.02)), haze_mix=0.1,
                   haze_rgb=(0.72, 0.76, 0.82))
    return cam, aer


def render_aerial(gl: GlRenderer3D, x0: float, y1: float, w: int, h: int, res: float, offset: np.ndarray,
                  light: Lighting, t: float, rng: np.random.Generator, lean: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The orthophoto (h, w, 3) uint8 whose pixel (c, r) is labelled local (x0 + (c + .5) res, y1 - (r + .5) res)
    but shows the scene at that point minus `offset` (the georeferencing error); raised points lean by
    `lean` metres per metre of height (see `GlRenderer3D.render_ortho`)."""
    ss = AERIAL_SUPERSAMPLE
    fine = res / ss
    out = np.zeros((h, w, 3), np.uint8)
    step = TILE_PX // ss
    for r0 in range(0, h, step):
        for c0 in range(0, w, step):
            th, tw = min(step, h - r0), min(step, w - c0)
            img = gl.render_ortho(x0 + c0 * res - offset[0], y1 - r0 * res - offset[1], tw * ss, th * ss, fine,
                                  epoch="aerial", t=t, light=light, lean=lean)
            out[r0:r0 + th, c0:c0 + tw] = cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA)
    out = cv2.GaussianBlur(out, (0, 0), 0.45)
    noisy = out.astype(np.float32) + rng.normal(0.0, 1.8, out.shape).astype(np.float32)
    out = np.clip(noisy + 0.5, 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        raise DataError("aerial: JPEG round trip failed")
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1])


def build_world3d(out: Path, scene: Scene, extent: tuple[float, float, float, float], epsg: int,
                  centre_utm: tuple[float, float], seed: int, ego_xy: np.ndarray, ego_t: np.ndarray,
                  progress: bool = False, clear_xy: np.ndarray | None = None) -> dict[str, Any]:
    """Write ground.tif, ground_mat.tif, scene3d.npz and the aerial mosaic.tif into `out` for the laid-out
    `scene` over `extent` (local metres x0, y0, x1, y1); returns the world.json entries to add.
    ego_xy (N, 2) local metres / ego_t (N,) s: the drive (objects keep clear of it); clear_xy (M, 2) local
    metres: points of other paths static objects keep clear of (`build_world`'s keep_clear)."""
    x0, y0, x1, y1 = extent
    r_ground, r_scene, r_light, r_aerial = (np.random.default_rng(s) for s in np.random.SeedSequence([seed, 3]).spawn(4))
    res_g = max(GROUND_M_PER_PX, max(x1 - x0, y1 - y0) / 8000.0)
    gw, gh = int(math.ceil((x1 - x0) / res_g)), int(math.ceil((y1 - y0) / res_g))
    canvas = _paint_ground(scene, x0, y1, gw, gh, res_g, r_ground)
    g_transform = write_geotiff(canvas, out / "ground.tif", epsg, centre_utm, seed, progress=progress)
    _write_rgb(out / "ground_mat.tif", canvas.mat, g_transform, epsg)
    mat = canvas.mat
    del canvas
    ground, _ = _read_rgb(out / "ground.tif")

    s3 = build_scene3d(scene, r_scene, ego_xy, ego_t, clear_xy=clear_xy)
    np.savez_compressed(out / "scene3d.npz", **s3.to_npz())
    cam_light, aer_light = lightings(r_light)
    ang = r_aerial.uniform(0, 2 * np.pi)
    offset = GEOREF_ERROR_M * r_aerial.uniform(0.8, 1.2) * np.array([math.cos(ang), math.sin(ang)])
    t_aerial = float(r_aerial.uniform(1e3, 1e5))
    lean_ang, lean_k = r_aerial.uniform(0, 2 * np.pi), float(r_aerial.uniform(*LEAN))
    lean = (lean_k * math.cos(lean_ang), lean_k * math.sin(lean_ang))
    flown = f"{int(r_aerial.integers(2007, 2011))}-{int(r_aerial.integers(9, 12)):02d}-{int(r_aerial.integers(1, 29)):02d}"
    w, h = int(round((x1 - x0) / AERIAL_M_PER_PX)), int(round((y1 - y0) / AERIAL_M_PER_PX))
    gl = GlRenderer3D(s3, ground, (x0, y1), res_g, mat)
    try:
        aerial = render_aerial(gl, x0, y1, w, h, AERIAL_M_PER_PX, offset, aer_light, t_aerial, r_aerial, lean)
    finally:
        gl.close()
    transform = Affine(AERIAL_M_PER_PX, 0.0, centre_utm[0] + x0, 0.0, -AERIAL_M_PER_PX, centre_utm[1] + y1)
    _write_rgb(out / "mosaic.tif", aerial, transform, epsg)
    log.info("3-D world: ground %d x %d px at %.2f m/px, aerial %d x %d px at %.2f m/px, georef offset (%.2f, %.2f) m",
             gw, gh, res_g, w, h, AERIAL_M_PER_PX, offset[0], offset[1])
    return {
        "realism": "3d", "mosaic": "mosaic.tif", "m_per_px": AERIAL_M_PER_PX, "scene3d": "scene3d.npz",
        "ground": "ground.tif", "ground_mat": "ground_mat.tif", "ground_m_per_px": res_g,
        "camera_light": cam_light.to_dict(), "camera_season": "summer",
        "aerial": {"light": aer_light.to_dict(), "m_per_px": AERIAL_M_PER_PX, "moving_cars_t_s": t_aerial,
                   "date": flown, "season": "autumn",
                   "georef_offset_m": [float(offset[0]), float(offset[1])],
                   "georef_offset_note": "a feature at true local (x, y) appears in mosaic.tif at (x + dx, y + dy)",
                   "lean_m_per_m": [lean[0], lean[1]],
                   "supersample": AERIAL_SUPERSAMPLE, "jpeg_quality": 85},
    }


class WorldRenderer3D:
    """Camera frames of a 3d world folder: `render(pose_utm, t)` -> uint8 RGB (camera.height, camera.width, 3).

    pose_utm: (E, N, theta) UTM metres and grid heading (ENU rad); t: drive seconds for the moving cars (None:
    none drawn). camera: the pinhole camera (intrinsics, mount, pitch). The scene and ground texture are read
    once; rendering runs on a private GL thread (see `render3d`)."""

    def __init__(self, world_dir: Path, camera: GroundCamera, meta: dict[str, Any] | None = None) -> None:
        import json

        world_dir = Path(world_dir)
        meta = meta if meta is not None else json.loads((world_dir / "world.json").read_text())
        if meta.get("realism") != "3d":
            raise DataError(f"{world_dir}: not a 3d world (world.json realism = {meta.get('realism', 'flat')!r})")
        try:
            with np.load(world_dir / meta["scene3d"]) as z:
                scene = Scene3D.from_npz(z)
            ground, gt = _read_rgb(world_dir / meta["ground"])
            with rasterio.open(world_dir / meta["ground_mat"]) as src:
                mat = src.read(1)
        except (OSError, KeyError, ValueError, rasterio.errors.RasterioIOError) as exc:
            raise DataError(f"{world_dir}: 3d world files unreadable ({exc})") from None
        self.camera = camera
        self.centre_utm = np.asarray(meta["centre_utm"], np.float64)
        self.light = Lighting(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in meta["camera_light"].items()})
        self.gl = GlRenderer3D(scene, ground, (gt.c - self.centre_utm[0], gt.f - self.centre_utm[1]), gt.a, mat)

    def local(self, pose_utm) -> tuple[float, float, float]:
        E, N, th = (float(v) for v in pose_utm)
        return E - self.centre_utm[0], N - self.centre_utm[1], th

    def render(self, pose_utm, t: float | None = None) -> np.ndarray:
        return self.gl.render_camera(self.camera, self.local(pose_utm), t, "camera", self.light)[0]

    def render_depth(self, pose_utm, t: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(RGB, depth along the optical axis in metres, inf for sky)."""
        return self.gl.render_camera(self.camera, self.local(pose_utm), t, "camera", self.light, depth=True)

    def ipm_valid(self, pose_utm, t: float | None = None, max_range_m: float = 80.0) -> np.ndarray:
        """(H, W) bool: pixels that see the bare ground plane within `max_range_m` (what an inverse perspective
        mapping may use): False for sky, facades, crowns, trunks, poles and cars, and ground hidden behind
        them. Ground truth for a matcher's masks."""
        fwd, _, ground = self.camera.pixel_ground_points(max_range_m)
        depth = self.render_depth(pose_utm, t)[1]
        return ground & (np.abs(depth - fwd) <= 0.03 * fwd + 0.05)

    def close(self) -> None:
        self.gl.close()


class LensRenderer3D:
    """`WorldRenderer3D` through a distorting lens (`LensCalibration`), as `render.LensRenderer` for flat
    worlds: a pinhole view wide enough for the lens's field of view, resampled once by the lens model."""

    def __init__(self, world_dir: Path, lens, mount_height_m: float, pitch_rad: float = 0.0,
                 meta: dict[str, Any] | None = None) -> None:
        from taco_mav.camera.calibration import lens_maps, wide_pinhole

        K, w, h = wide_pinhole(lens)
        self.lens = lens
        self.pinhole = WorldRenderer3D(world_dir, GroundCamera(K, w, h, mount_height_m, pitch_rad), meta)
        self._mx, self._my = cv2.convertMaps(*lens_maps(lens, K), cv2.CV_16SC2)

    def render(self, pose_utm, t: float | None = None) -> np.ndarray:
        return cv2.remap(self.pinhole.render(pose_utm, t), self._mx, self._my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def close(self) -> None:
        self.pinhole.close()


def world_is_3d(world_dir: Path) -> bool:
    """Whether DIR/world.json says realism 3d (False when unreadable: the caller reports that)."""
    import json

    try:
        return json.loads((Path(world_dir) / "world.json").read_text()).get("realism") == "3d"
    except (OSError, ValueError, AttributeError):
        return False
