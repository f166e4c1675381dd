"""Inverse perspective mapping: a ground camera image resampled to a heading-up bird's-eye view (BEV).

Frames and units:
- BEV pixels (i, j) = (column, row) with OpenCV's convention (pixel centres at integers). The vehicle (the
  ground point below the camera) sits at pixel `vehicle_px` = (u0, v0); by default bottom-centre,
  ((W - 1) / 2, H - 1). Forward is image-up, left is image-left, the same heading-up convention as the
  satellite crops: BEV pixel (i, j) shows the ground at forward = (v0 - j) m, left = (u0 - i) m, with m the
  BEV resolution in metres per pixel.
- camera pixels follow `taco_mav.camera.geometry.GroundCamera` (flat ground, mount height, pitch).

The remap maps are computed once. Near the vehicle one BEV pixel spans many camera pixels, so rows of the BEV
whose camera footprint exceeds 2^k pixels sample level k of a Gaussian image pyramid (pyrDown) instead of the
full image; for a pitch-only camera the footprint depends on the BEV row only, so each level is a row band.
"""

from __future__ import annotations

import logging
import math

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["BevProjector"]


class BevProjector:
    """Projects camera images (H, W) or (H, W, 3) to a BEV of `size_px` = S or (width, height) pixels at
    `m_per_px` metres per pixel, keeping ground within `max_range_m` of the vehicle.

    vehicle_px: BEV pixel (u0, v0) of the vehicle; default bottom-centre ((W - 1) / 2, H - 1).
    levels: image pyramid levels available for anti-aliasing (1 = full resolution only).
    """

    def __init__(self, camera: GroundCamera, size_px: int | tuple[int, int], m_per_px: float, max_range_m: float,
                 vehicle_px: tuple[float, float] | None = None, levels: int = 4) -> None:
        W, H = (size_px, size_px) if isinstance(size_px, (int, np.integer)) else (int(size_px[0]), int(size_px[1]))
        if W < 2 or H < 2 or m_per_px <= 0 or max_range_m <= 0:
            raise DataError(f"BEV size {W}x{H} px, {m_per_px} m/px, range {max_range_m} m: all must be positive")
        self.camera = camera
        self.width, self.height = W, H
        self.m_per_px = float(m_per_px)
        self.max_range_m = float(max_range_m)
        self.vehicle_px = ((W - 1) / 2.0, H - 1.0) if vehicle_px is None else (float(vehicle_px[0]), float(vehicle_px[1]))
        u0, v0 = self.vehicle_px
        i, j = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        fwd = (v0 - j) * self.m_per_px
        left = (u0 - i) * self.m_per_px
        G = camera.ground_to_image
        x = G[0, 0] * fwd + G[0, 1] * left + G[0, 2]
        y = G[1, 0] * fwd + G[1, 1] * left + G[1, 2]
        z = G[2, 0] * fwd + G[2, 1] * left + G[2, 2]
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        u, v = x / zs, y / zs
        self.mask = (front & (fwd > 0.5) & (np.hypot(fwd, left) <= self.max_range_m)
                     & (u >= 0) & (u <= camera.width - 1) & (v >= 0) & (v <= camera.height - 1))
        if not self.mask.any():
            raise DataError("BEV: no BEV pixel sees the camera's ground; check size, resolution and camera pitch")
        self.fwd_m, self.left_m = fwd, left
        # Camera pixels per BEV pixel (geometric mean of the two axes) -> pyramid level per BEV row.
        du = np.abs(np.gradient(u, axis=1))
        dv = np.abs(np.gradient(v, axis=0))
        foot = np.sqrt(np.maximum(du * dv, 1e-12))
        rows = np.flatnonzero(self.mask.any(axis=1))
        self._r0, self._r1 = int(rows[0]), int(rows[-1]) + 1
        self.levels = max(1, int(levels))
        self._bands: list[tuple[int, int, int, np.ndarray, np.ndarray]] = []
        for r in range(self._r0, self._r1):
            f = float(np.median(foot[r][self.mask[r]])) if self.mask[r].any() else 1.0
            lvl = int(np.clip(math.floor(math.log2(max(f, 1.0))), 0, self.levels - 1))
            if self._bands and self._bands[-1][2] == lvl:
                a, _, _, _, _ = self._bands[-1]
                self._bands[-1] = (a, r + 1, lvl, np.empty(0), np.empty(0))
            else:
                self._bands.append((r, r + 1, lvl, np.empty(0), np.empty(0)))
        # pyrDown centres level-k pixel j on full-resolution pixel 2^k j: x_k = u / 2^k.
        off = np.where(self.mask, 0.0, -1e4)  # invalid pixels sample far outside -> border value 0
        self._bands = [(a, b, lvl, ((u[a:b] + off[a:b]) / 2**lvl).astype(np.float32),
                        ((v[a:b] + off[a:b]) / 2**lvl).astype(np.float32)) for a, b, lvl, _, _ in self._bands]
        self._max_level = max(lvl for _, _, lvl, _, _ in self._bands)
        self.mask_u8 = self.mask.astype(np.uint8)
        log.debug("BEV %dx%d px at %.2f m/px: rows %d..%d, bands %s", W, H, m_per_px, self._r0, self._r1,
                  [(a, b, lvl) for a, b, lvl, _, _ in self._bands])

    def ground_of_pixel(self, uv: np.ndarray) -> np.ndarray:
        """BEV pixels (N, 2) as (col, row) -> ground (forward, left) metres, shape (N, 2)."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        u0, v0 = self.vehicle_px
        return np.c_[(v0 - uv[:, 1]) * self.m_per_px, (u0 - uv[:, 0]) * self.m_per_px]

    def pixel_of_ground(self, fwd_left: np.ndarray) -> np.ndarray:
        """Ground (forward, left) metres (N, 2) -> BEV pixels (col, row), shape (N, 2)."""
        fl = np.atleast_2d(np.asarray(fwd_left, dtype=float))
        u0, v0 = self.vehicle_px
        return np.c_[u0 - fl[:, 1] / self.m_per_px, v0 - fl[:, 0] / self.m_per_px]

    def project(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera image (H, W) or (H, W, 3), any dtype -> (BEV float32 (S_h, S_w[, 3]), mask bool (S_h, S_w)).

        Pixels outside the mask (beyond range, outside the camera's view, above the horizon) are 0.
        """
        cam = self.camera
        if image.shape[:2] != (cam.height, cam.width):
            raise DataError(f"BEV: image is {image.shape[1]}x{image.shape[0]} px, camera model is "
                            f"{cam.width}x{cam.height}")
        img = image.astype(np.float32, copy=False)
        pyramid = [img]
        for _ in range(self._max_level):
            pyramid.append(cv2.pyrDown(pyramid[-1]))
        out = np.zeros((self.height, self.width) + img.shape[2:], np.float32)
        for a, b, lvl, mx, my in self._bands:
            out[a:b] = cv2.remap(pyramid[lvl], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                 borderValue=0)
        return out, self.mask
