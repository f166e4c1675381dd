"""Flat-ground pinhole geometry shared by the synthetic renderer and inverse perspective mapping.

Frames: the vehicle's planar body frame is (forward, left) metres on the ground, origin directly below the
camera. The camera (OpenCV convention: x right, y down, z forward) sits `mount_height_m` above the ground and
is pitched down by `pitch_rad`. Image pixels are (u, v) = (column, row). World ground is ENU metres, heading
theta ENU radians (0 = east, CCW). A north-up GeoTIFF maps ENU (E, N) to (col, row) by its affine transform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taco_mav.config import CameraConfig


@dataclass(frozen=True)
class GroundCamera:
    """A pinhole camera over a flat ground plane. K: 3x3 intrinsics in pixels; size: (width, height) px."""

    K: np.ndarray
    width: int
    height: int
    mount_height_m: float
    pitch_rad: float = 0.0

    @classmethod
    def from_config(cls, cfg: CameraConfig, scale: float = 1.0) -> "GroundCamera":
        """Build from a profile's camera section; `scale` resizes the image (e.g. 0.5 for half size)."""
        K = np.array([[cfg.fx * scale, 0.0, cfg.cx * scale], [0.0, cfg.fy * scale, cfg.cy * scale], [0.0, 0.0, 1.0]])
        return cls(K, int(round(cfg.width_px * scale)), int(round(cfg.height_px * scale)), cfg.mount_height_m, cfg.pitch_rad)

    @property
    def ground_to_image(self) -> np.ndarray:
        """3x3 homography from ground (forward, left, 1) metres to homogeneous pixels (u, v, 1)."""
        s, c, h = np.sin(self.pitch_rad), np.cos(self.pitch_rad), self.mount_height_m
        M = np.array([[0.0, -1.0, 0.0], [-s, 0.0, h * c], [c, 0.0, h * s]])
        return self.K @ M

    @property
    def image_to_ground(self) -> np.ndarray:
        """3x3 homography from pixels (u, v, 1) to ground (forward, left, 1); valid where the ray hits ground."""
        return np.linalg.inv(self.ground_to_image)

    def project(self, fwd_left: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ground points (N, 2) metres -> pixels (N, 2) and a mask of points in front of the camera."""
        pts = np.c_[fwd_left, np.ones(len(fwd_left))] @ self.ground_to_image.T
        in_front = pts[:, 2] > 1e-9
        uv = pts[:, :2] / np.where(in_front, pts[:, 2], 1.0)[:, None]
        return uv, in_front

    def pixel_ground_points(self, max_range_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every pixel: ground forward and left (H, W) float32 metres, and a mask of pixels seeing ground
        closer than `max_range_m` (False above the horizon)."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        Hinv = self.image_to_ground
        gx = Hinv[0, 0] * u + Hinv[0, 1] * v + Hinv[0, 2]
        gy = Hinv[1, 0] * u + Hinv[1, 1] * v + Hinv[1, 2]
        gw = Hinv[2, 0] * u + Hinv[2, 1] * v + Hinv[2, 2]
        # The ray hits the ground in front of the camera iff the projected forward distance is positive.
        safe = np.where(np.abs(gw) < 1e-12, 1e-12, gw)
        fwd, left = gx / safe, gy / safe
        mask = (fwd > 0.5) & (fwd < max_range_m) & (np.abs(left) < max_range_m)
        return fwd.astype(np.float32), left.astype(np.float32), mask
