"""Mount height and pitch: measure them from marks on the ground, and check the profile's pitch against the
horizon of live frames.

Frames and units: undistorted (pinhole) frames of the camera model, pixels (u, v) = (column, row); pitch in
radians, positive = looking down (`CameraConfig.pitch_rad`); a level camera sees the horizon at row
v_h = cy - fy tan(pitch). Ground distances are metres along the ground from the point below the camera.

The horizon check is deliberately coarse: the sky-ground boundary of a real scene lies above the true horizon
behind trees and buildings and, on a renderer with a finite range, a little below it; it catches a pitch off by
degrees (a sign error, degrees typed as radians, a camera knocked down), not a fraction of one.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.errors import ConfigError

log = logging.getLogger(__name__)

__all__ = ["HorizonCheck", "HorizonWarning", "horizon_row", "mount_from_marks"]

HORIZON_TOLERANCE_RAD = math.radians(3.0)  # median horizon pitch this far from the profile's: warn
HORIZON_MIN_CONTRAST = 10.0  # grey levels (0-255) between the bands above and below a horizon candidate


def horizon_row(image: np.ndarray, min_contrast: float = HORIZON_MIN_CONTRAST) -> float | None:
    """Row (px, may be fractional) of the sky-ground boundary of an image (H, W[, 3]) uint8 RGB or grey: the
    strongest step of the per-row median brightness (central 80 % of the columns) with a band above it at most
    half as textured as the band below (sky over ground). None when no step reaches `min_contrast` grey levels."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    H, W = grey.shape
    if H < 8 or W < 8:
        return None
    g = grey[:, int(0.1 * W):int(0.9 * W):max(1, W // 200)].astype(np.float32)
    level = np.median(g, axis=1)
    texture = np.median(np.abs(np.diff(g, axis=1)), axis=1)
    k = max(2, H // 40)
    c = np.concatenate([[0.0], np.cumsum(level)])
    ct = np.concatenate([[0.0], np.cumsum(texture)])
    v = np.arange(k, H - k + 1)  # candidate boundary between rows v - 1 and v
    step = np.abs((c[v] - c[v - k]) - (c[v + k] - c[v])) / k
    smoother_above = (ct[v] - ct[v - k]) < 0.5 * (ct[v + k] - ct[v])  # sky (or haze) over textured ground
    score = np.where(smoother_above, step, 0.0)
    i = int(np.argmax(score))
    return float(v[i]) - 0.5 if score[i] >= min_contrast else None


@dataclass(frozen=True)
class HorizonWarning:
    """The horizon of recent frames disagrees with the profile's pitch. text: STATUSTEXT (<= 50 chars);
    pitches in rad (positive = down); rows in px of the undistorted frame; samples: frames in the median."""

    text: str
    measured_pitch_rad: float
    configured_pitch_rad: float
    horizon_row_px: float
    expected_row_px: float
    samples: int


class HorizonCheck:
    """Watches the horizon of undistorted frames of `camera` (called from the frame worker: `observe`) and
    queues a `HorizonWarning` (taken on the loop thread: `take_warnings`) when the median pitch of the last
    `window` frames with a horizon (at least `min_samples`) is more than `tolerance_rad` from the camera's
    pitch, at most once per `interval_s` (s on `clock`). Off when the expected horizon is outside the frame."""

    def __init__(self, camera: GroundCamera, tolerance_rad: float = HORIZON_TOLERANCE_RAD, window: int = 15,
                 min_samples: int = 5, interval_s: float = 60.0, clock: Callable[[], float] = time.monotonic) -> None:
        K = camera.K
        self.fy, self.cy, self.pitch = float(K[1, 1]), float(K[1, 2]), float(camera.pitch_rad)
        self.expected_row = self.cy - self.fy * math.tan(self.pitch)
        self.enabled = 0.05 * camera.height <= self.expected_row <= 0.95 * camera.height
        self.tolerance, self.min_samples, self.interval_s, self.clock = tolerance_rad, min_samples, interval_s, clock
        self._pitches: deque[float] = deque(maxlen=window)
        self._last_warning = -math.inf
        self._pending: list[HorizonWarning] = []
        self._lock = threading.Lock()
        self.warnings = 0
        if not self.enabled:
            log.info("horizon check off: the profile's pitch puts the horizon at row %.0f, outside the frame",
                     self.expected_row)

    def pitch_of_row(self, row: float) -> float:
        """The camera pitch (rad, positive down) that puts the horizon at image row `row` (px)."""
        return math.atan2(self.cy - row, self.fy)

    def observe(self, image: np.ndarray) -> float | None:
        """Measure one undistorted frame; the pitch its horizon implies (rad), or None (no horizon seen)."""
        if not self.enabled:
            return None
        row = horizon_row(image)
        if row is None:
            return None
        pitch = self.pitch_of_row(row)
        with self._lock:
            self._pitches.append(pitch)
            n = len(self._pitches)
            med = float(np.median(self._pitches))
            now = self.clock()
            agrees = abs(med - self.pitch) <= self.tolerance
            if n < self.min_samples or agrees or now - self._last_warning < self.interval_s:
                return pitch
            self._last_warning = now
            self.warnings += 1
            w = HorizonWarning(f"camera pitch {math.degrees(med):+.1f}deg? profile {math.degrees(self.pitch):+.1f}",
                               med, self.pitch, self.cy - self.fy * math.tan(med), self.expected_row, n)
            self._pending.append(w)
        log.warning("camera horizon at row %.0f (pitch %.1f deg, median of %d frames) but camera.pitch_rad %.3f "
                    "(%.1f deg) puts it at row %.0f: check the mount (docs/camera.md)", w.horizon_row_px,
                    math.degrees(med), n, self.pitch, math.degrees(self.pitch), self.expected_row)
        return pitch

    def take_warnings(self) -> list[HorizonWarning]:
        """The warnings queued since the last call."""
        with self._lock:
            out, self._pending = self._pending, []
        return out


def mount_from_marks(camera: GroundCamera, marks: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """Mount height (m) and pitch (rad, positive down) from marks on flat ground straight ahead: (row px in the
    undistorted frame, distance m from the point below the camera) for two or more marks at different
    distances. Least squares over the marks' depression angles atan(h / d) = atan((v - cy) / fy) + pitch."""
    from scipy.optimize import least_squares

    rows = np.array([m[0] for m in marks], float)
    dist = np.array([m[1] for m in marks], float)
    if len(marks) < 2 or len(np.unique(dist)) < 2 or (dist <= 0).any():
        raise ConfigError("mount_from_marks: give at least two marks at different positive distances")
    fy, cy = float(camera.K[1, 1]), float(camera.K[1, 2])
    below_axis = np.arctan((rows - cy) / fy)

    def residual(x: np.ndarray) -> np.ndarray:
        return np.arctan(x[0] / dist) - below_axis - x[1]

    sol = least_squares(residual, x0=np.array([1.0, 0.0]), bounds=([1e-3, -1.5], [100.0, 1.5]))
    return float(sol.x[0]), float(sol.x[1])
