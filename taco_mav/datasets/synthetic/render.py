"""Flat-world ground-camera renderer: what the vehicle's camera would see if the satellite mosaic were the ground.

Frames and units:
- world: UTM easting/northing metres (ENU); pose (E, N, theta) with theta the heading in ENU radians
  (0 = east, CCW positive); the camera sits above (E, N) looking along theta.
- vehicle ground frame: (forward, left) metres, origin below the camera (see `taco_mav.camera.geometry`).
- mosaic: a north-up RGB array (H, W, 3) uint8 with a rasterio `Affine` mapping (col, row) of pixel corners to
  (E, N); pixel (i, j) covers [i, i+1) x [j, j+1) so its centre is at (i + 0.5, j + 0.5). OpenCV samples pixel i
  at coordinate i, hence the -0.5 shift below.

Every pixel's ground point is computed once (`GroundCamera.pixel_ground_points`); a frame is then two affine
combinations per pixel (cv2.addWeighted) and one `cv2.remap` per pyramid level. Far rows, whose ground footprint
covers several mosaic pixels, sample a pre-blurred (pyrDown) level of the mosaic to avoid aliasing. For a
pitch-only camera the footprint depends on the row only, so each level is a contiguous band of rows.
The source is sliced to a window around the pose before remapping (a numpy view, no copy), which keeps OpenCV's
fixed-point coordinates in range for mosaics wider than 32k pixels.

`LensRenderer` draws through a distorting lens (a `LensCalibration`): a pinhole view wide enough for the lens's
field of view, resampled once by the lens model (raw pixel -> ray -> pinhole pixel, `lens_maps`), so a camera
pipeline that undistorts its frames can be exercised end to end.
"""

from __future__ import annotations

import logging
import math

import cv2
import numpy as np
from rasterio.transform import Affine

from taco_mav.camera.calibration import LensCalibration, lens_maps, wide_pinhole
from taco_mav.camera.geometry import GroundCamera
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["GroundRenderer", "LensRenderer"]


class GroundRenderer:
    """Renders uint8 RGB (camera.height, camera.width, 3) views of a flat textured world.

    mosaic: uint8 RGB (H, W, 3), north-up. transform: rasterio Affine, (col, row) -> (E, N) UTM metres.
    camera: the ground camera (intrinsics, mount height, pitch). max_range_m: ground farther than this is drawn
    as haze/horizon colour. sky_rgb / horizon_rgb: sky gradient colours (zenith-side top row, horizon).
    haze_m: e-folding distance of the distance haze in metres (None = no haze). levels: pyramid levels
    (1 = full resolution only). fill_rgb: ground colour off the mosaic (default: the mosaic's mean colour).
    """

    def __init__(
        self,
        mosaic: np.ndarray,
        transform: Affine,
        camera: GroundCamera,
        max_range_m: float = 80.0,
        sky_rgb: tuple[int, int, int] = (110, 150, 210),
        horizon_rgb: tuple[int, int, int] = (200, 210, 220),
        haze_m: float | None = 250.0,
        levels: int = 3,
        fill_rgb: tuple[int, int, int] | None = None,
    ) -> None:
        if mosaic.ndim != 3 or mosaic.shape[2] != 3 or mosaic.dtype != np.uint8:
            raise DataError(f"renderer mosaic must be uint8 RGB (H, W, 3), got {mosaic.dtype} {mosaic.shape}")
        if max_range_m <= 1.0:
            raise DataError(f"renderer max_range_m must exceed 1 m, got {max_range_m}")
        self.camera = camera
        self.max_range_m = float(max_range_m)
        self._transform = transform
        self._inv = ~transform
        m_per_px = math.sqrt(abs(transform.a * transform.e - transform.b * transform.d))
        if fill_rgb is None:
            step = max(1, int(math.sqrt(mosaic.shape[0] * mosaic.shape[1] / 1e5)))
            fill_rgb = tuple(int(c) for c in mosaic[::step, ::step].reshape(-1, 3).mean(axis=0))
        self._fill = tuple(float(c) for c in fill_rgb)

        # Mosaic pyramid: level k has 2^k coarser pixels (Gaussian pre-blur from pyrDown).
        self._pyramid = [np.ascontiguousarray(mosaic)]
        for _ in range(1, max(1, levels)):
            prev = self._pyramid[-1]
            if min(prev.shape[:2]) < 4:
                break
            self._pyramid.append(cv2.pyrDown(prev))

        H, W = camera.height, camera.width
        fwd, left, mask = camera.pixel_ground_points(self.max_range_m)
        self._mask = mask
        rows_with_ground = np.flatnonzero(mask.any(axis=1))
        if len(rows_with_ground) == 0:
            raise DataError("renderer: no camera pixel sees the ground within max_range_m; check pitch/height")
        self._r0, self._r1 = int(rows_with_ground[0]), int(rows_with_ground[-1]) + 1
        self._fwd = np.ascontiguousarray(fwd[self._r0 : self._r1])
        self._left = np.ascontiguousarray(left[self._r0 : self._r1])
        self._reach_m = float(np.hypot(fwd[mask], left[mask]).max()) + 1.0

        # Ground footprint of a pixel in mosaic pixels: geometric mean of the forward (row-to-row) and lateral
        # (column-to-column) spacing; choose the pyramid level per row band from its median footprint.
        d_fwd = np.abs(np.gradient(fwd.astype(np.float64), axis=0))
        d_left = np.abs(np.gradient(left.astype(np.float64), axis=1))
        foot = np.sqrt(np.maximum(d_fwd * d_left, 1e-12)) / m_per_px
        bands: list[tuple[int, int, int]] = []
        for r in range(self._r0, self._r1):
            valid = mask[r]
            f = float(np.median(foot[r][valid])) if valid.any() else 1.0
            lvl = int(np.clip(math.floor(math.log2(max(f, 1.0))), 0, len(self._pyramid) - 1))
            if bands and bands[-1][2] == lvl:
                bands[-1] = (bands[-1][0], r + 1, lvl)
            else:
                bands.append((r, r + 1, lvl))
        self._bands = [(a - self._r0, b - self._r0, lvl) for a, b, lvl in bands]

        # Background: sky gradient above the horizon, horizon colour on ground beyond max range.
        horizon_v = self._horizon_row()
        sky = np.asarray(sky_rgb, np.float32)
        hor = np.asarray(horizon_rgb, np.float32)
        v = np.arange(H, dtype=np.float32)[:, None]
        a = np.clip(v / max(horizon_v, 1.0), 0.0, 1.0)
        bg = (1.0 - a) * sky + a * hor
        self._background = np.ascontiguousarray(np.broadcast_to(bg[:, None, :], (H, W, 3)).round().astype(np.uint8))
        self._band_invalid = ~mask[self._r0 : self._r1]
        self._any_invalid = bool(self._band_invalid.any())

        # Distance haze: out = ground * (1 - a) + horizon * a, a = 1 - exp(-d / haze_m).
        self._haze_keep: np.ndarray | None = None
        self._haze_add: np.ndarray | None = None
        if haze_m is not None and haze_m > 0:
            dist = np.hypot(self._fwd, self._left)
            alpha = (1.0 - np.exp(-dist / float(haze_m))).astype(np.float32)
            self._haze_keep = np.repeat((1.0 - alpha)[:, :, None], 3, axis=2)
            self._haze_add = (alpha[:, :, None] * hor).astype(np.float32)
        log.debug("renderer: ground rows %d..%d, bands %s, reach %.1f m", self._r0, self._r1, self._bands, self._reach_m)

    def _horizon_row(self) -> float:
        """Image row of the horizon (ground at infinity straight ahead), clipped to the image."""
        K, p = self.camera.K, self.camera.pitch_rad
        v = K[1, 2] - K[1, 1] * math.tan(p)
        return float(np.clip(v, 0.0, self.camera.height - 1))

    def render(self, pose_utm: tuple[float, float, float] | np.ndarray) -> np.ndarray:
        """The camera view from pose (E, N, theta): UTM metres and ENU heading radians -> uint8 RGB (H, W, 3)."""
        E, N, theta = (float(x) for x in pose_utm)
        c, s = math.cos(theta), math.sin(theta)
        out = self._background.copy()
        band_img = np.empty((self._r1 - self._r0, self.camera.width, 3), np.uint8)
        inv = self._inv
        for a, b, lvl in self._bands:
            src, (c0, r0) = self._window(E, N, lvl)
            k = float(2**lvl)
            # continuous mosaic (col, row) = inv * (E + c f - s l, N + s f + c l). pyrDown centres level-k pixel
            # j on level-0 pixel 2^k j, whose centre is continuous col 2^k j + 0.5, so OpenCV's level-k
            # coordinate is x_k = (col - 0.5) / 2^k minus the window origin.
            ax = (inv.a * c + inv.b * s) / k
            bx = (-inv.a * s + inv.b * c) / k
            cx = (inv.a * E + inv.b * N + inv.c - 0.5) / k - c0
            ay = (inv.d * c + inv.e * s) / k
            by = (-inv.d * s + inv.e * c) / k
            cy = (inv.d * E + inv.e * N + inv.f - 0.5) / k - r0
            f, l = self._fwd[a:b], self._left[a:b]
            map_x = cv2.addWeighted(f, ax, l, bx, cx)
            map_y = cv2.addWeighted(f, ay, l, by, cy)
            if src.size == 0:
                band_img[a:b] = np.asarray(self._fill, np.uint8)
                continue
            cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, dst=band_img[a:b],
                      borderMode=cv2.BORDER_CONSTANT, borderValue=self._fill)
        if self._haze_keep is not None:
            hazed = cv2.multiply(band_img, self._haze_keep, dtype=cv2.CV_32F)
            cv2.add(hazed, self._haze_add, dst=hazed)
            band_img = hazed.astype(np.uint8)  # values stay within [0, 255]: a convex blend of two colours
        target = out[self._r0 : self._r1]
        if self._any_invalid:
            np.copyto(target, band_img, where=~self._band_invalid[:, :, None])
        else:
            target[...] = band_img
        return out

    def _window(self, E: float, N: float, level: int) -> tuple[np.ndarray, tuple[int, int]]:
        """A view of pyramid `level` covering every ground point within reach of (E, N), and its origin
        (col, row) in that level's pixels."""
        img = self._pyramid[level]
        k = 2**level
        r = self._reach_m
        cols, rows = [], []
        for dx in (-r, r):
            for dy in (-r, r):
                col, row = self._inv @ (E + dx, N + dy)
                cols.append(col)
                rows.append(row)
        c0 = int(math.floor(min(cols) / k)) - 2
        c1 = int(math.ceil(max(cols) / k)) + 3
        r0 = int(math.floor(min(rows) / k)) - 2
        r1 = int(math.ceil(max(rows) / k)) + 3
        h, w = img.shape[:2]
        c0c, c1c, r0c, r1c = max(c0, 0), min(c1, w), max(r0, 0), min(r1, h)
        if c0c >= c1c or r0c >= r1c:
            return img[0:0, 0:0], (c0c, r0c)
        return img[r0c:r1c, c0c:c1c], (c0c, r0c)


class LensRenderer:
    """Renders uint8 RGB (lens.height, lens.width, 3) views of a flat textured world through a distorting lens.

    mosaic, transform: as `GroundRenderer`; lens: the lens (intrinsics, distortion, image size);
    mount_height_m, pitch_rad: the mount (metres above the ground; radians, positive = looking down);
    renderer_kw: more `GroundRenderer` arguments (max_range_m, haze_m, ...). `pinhole` is the wide pinhole
    renderer drawn first (its camera: the lens's focal length, a view holding the lens's whole field of view).
    """

    def __init__(self, mosaic: np.ndarray, transform: Affine, lens: LensCalibration, mount_height_m: float,
                 pitch_rad: float = 0.0, **renderer_kw: object) -> None:
        K, w, h = wide_pinhole(lens)
        self.lens = lens
        self.pinhole = GroundRenderer(mosaic, transform, GroundCamera(K, w, h, mount_height_m, pitch_rad),
                                      **renderer_kw)  # type: ignore[arg-type]
        self._mx, self._my = cv2.convertMaps(*lens_maps(lens, K), cv2.CV_16SC2)

    def render(self, pose_utm: tuple[float, float, float] | np.ndarray) -> np.ndarray:
        """The distorted camera view from pose (E, N, theta): UTM metres and ENU heading radians."""
        return cv2.remap(self.pinhole.render(pose_utm), self._mx, self._my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
