"""An appearance gap between a ground camera and its satellite map, made on purpose (tests and evaluation).

A flat synthetic world renders its camera frames from the very mosaic the matcher matches against; a real rover
sees a map taken on another day by another sensor. Two seeded, deterministic changes reproduce the main parts
of that gap on a flat world, so that matchers can be measured under it:

- `alter_mosaic`: the *map* re-photographed: exposure gain and gamma, a season tint (a channel mix that turns
  vegetation from green to brown), shadow blobs moved to new places (darker, bluish, soft-edged), a coarser,
  blurred sensor (`resolution_m`), and optionally (`fold`) a change of the brightness order of materials, the
  part of a real cross-sensor gap that defeats grey-level correlation (an edge keeps its place and direction,
  not its polarity);
- `occlude_frame`: the *camera* view with vertical structure drawn in: upright boxes (poles, car sides,
  facades, trunks) standing on the ground at random places in view, textured, in perspective, from their
  ground contact up to their height. The flat-ground IPM smears such a box over the ground behind it.

Frames and units: mosaics are north-up uint8 RGB (H, W, 3) at `m_per_px`; camera frames uint8 RGB (H, W, 3)
of a `GroundCamera` (x right, y down, pitch down positive); occluder placement in the vehicle's (forward,
left) metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera

__all__ = ["MapGap", "FrameGap", "alter_mosaic", "occlude_frame", "SEASONS"]

# Channel mixes (rows: output R, G, B from input R, G, B). "autumn" pulls green into red and drops green's
# brightness below red's: grass goes brown and brighter in grey than asphalt where it was darker before.
SEASONS: dict[str, np.ndarray] = {
    "none": np.eye(3, dtype=np.float32),
    "autumn": np.array([[0.75, 0.70, 0.05], [0.20, 0.55, 0.10], [0.05, 0.15, 0.55]], np.float32),
    "spring": np.array([[0.80, 0.15, 0.05], [0.05, 1.05, 0.05], [0.05, 0.10, 0.90]], np.float32),
}


@dataclass(frozen=True)
class MapGap:
    """How the satellite map differs from the world the camera sees. gain, gamma: out = 255 (gain x)^gamma,
    x in [0, 1]; season: a key of SEASONS; shadows: number of moved shadow blobs per km^2 (each 5-20 m across);
    shadow_depth: their darkening (0 none, 1 black); resolution_m: the map's native ground resolution
    (downsampled to it and back, area-averaged), blur_m: Gaussian blur sigma on top, metres; fold: when set, a
    non-monotonic tone curve out = |x - fold| / max(fold, 1 - fold) after the rest, so materials darker than
    `fold` change their brightness order (asphalt darker than the verge in the camera, brighter in the map)."""

    gain: float = 0.85
    gamma: float = 1.35
    season: str = "autumn"
    shadows_per_km2: float = 600.0
    shadow_depth: float = 0.55
    resolution_m: float = 0.4
    blur_m: float = 0.3
    fold: float | None = None


@dataclass(frozen=True)
class FrameGap:
    """Vertical occluders drawn into camera frames: `count` boxes per frame, ground contact 6-30 m ahead and
    up to 12 m to either side, widths `width_m` (lo, hi), heights `height_m` (lo, hi)."""

    count: int = 3
    width_m: tuple[float, float] = (0.4, 4.5)
    height_m: tuple[float, float] = (1.2, 8.0)
    fwd_m: tuple[float, float] = (6.0, 30.0)
    left_m: tuple[float, float] = (-12.0, 12.0)


def alter_mosaic(rgb: np.ndarray, m_per_px: float, seed: int, gap: MapGap = MapGap()) -> np.ndarray:
    """The map re-photographed under `gap`: uint8 RGB (H, W, 3) in, same shape out, deterministic in seed."""
    rng = np.random.default_rng(seed)
    img = rgb.astype(np.float32) / 255.0
    if gap.season not in SEASONS:
        raise ValueError(f"season {gap.season!r} is not one of {', '.join(SEASONS)}")
    img = cv2.transform(img, SEASONS[gap.season])
    H, W = img.shape[:2]
    if gap.shadows_per_km2 > 0 and gap.shadow_depth > 0:
        shade = np.zeros((H, W), np.float32)
        area_km2 = H * W * m_per_px**2 / 1e6
        for _ in range(int(round(gap.shadows_per_km2 * area_km2))):
            cx, cy = rng.uniform(0, W), rng.uniform(0, H)
            ax, ay = rng.uniform(2.5, 10.0, 2) / m_per_px
            cv2.ellipse(shade, ((float(cx), float(cy)), (float(2 * ax), float(2 * ay)), float(rng.uniform(0, 180))),
                        1.0, -1)
        shade = cv2.GaussianBlur(shade, (0, 0), 0.6 / m_per_px)
        tint = np.array([1.0, 1.0, 1.15], np.float32)  # skylight: shadows are bluish
        img = img * (1.0 - gap.shadow_depth * shade[:, :, None]) * (1.0 + (tint - 1.0) * shade[:, :, None])
    img = np.clip(gap.gain * img, 0.0, 1.0) ** gap.gamma
    if gap.resolution_m > m_per_px:
        f = m_per_px / gap.resolution_m
        small = cv2.resize(img, (max(1, round(W * f)), max(1, round(H * f))), interpolation=cv2.INTER_AREA)
        img = cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR)
    if gap.blur_m > 0:
        img = cv2.GaussianBlur(img, (0, 0), gap.blur_m / m_per_px)
    if gap.fold is not None:
        img = np.abs(img - gap.fold) / max(gap.fold, 1.0 - gap.fold)
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _project_points(camera: GroundCamera, fwd: np.ndarray, left: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Points (forward, left, up) metres in the vehicle frame -> pixels (N, 2); up from the ground."""
    s, c, h = math.sin(camera.pitch_rad), math.cos(camera.pitch_rad), camera.mount_height_m
    cam = np.stack([-left, -s * fwd + c * (h - up), c * fwd + s * (h - up)])
    p = camera.K @ cam
    return (p[:2] / p[2]).T


def occlude_frame(rgb: np.ndarray, camera: GroundCamera, seed: int,
                  gap: FrameGap = FrameGap()) -> tuple[np.ndarray, np.ndarray]:
    """Draw `gap.count` upright textured boxes into a camera frame (far ones first, so near ones occlude them).
    Returns (uint8 RGB frame, bool mask (H, W) of the occluder pixels). Deterministic in seed."""
    rng = np.random.default_rng(seed)
    out = rgb.copy()
    mask = np.zeros(rgb.shape[:2], np.uint8)
    boxes = []
    for _ in range(gap.count):
        fwd = rng.uniform(*gap.fwd_m)
        left = rng.uniform(*gap.left_m)
        boxes.append((fwd, left, rng.uniform(*gap.width_m), rng.uniform(*gap.height_m), rng.uniform(0.3, 1.8),
                      rng.uniform(40, 200, 3), int(rng.integers(1 << 30))))
    for fwd, left, width, height, depth, colour, tex_seed in sorted(boxes, key=lambda b: -b[0]):
        # the box's camera-facing side (a rectangle at distance fwd) and one visible side face, as a polygon
        half = width / 2.0
        near_side = left - half if left > 0 else left + half  # the face towards the camera's centre line
        corners = [(fwd, left - half), (fwd, left + half)]
        side = [(fwd, near_side), (fwd + depth, near_side)]
        polys = []
        for (f0, l0), (f1, l1) in (corners, side):
            pts = _project_points(camera, np.array([f0, f1, f1, f0]), np.array([l0, l1, l1, l0]),
                                  np.array([0.0, 0.0, height, height]))
            polys.append(np.round(pts).astype(np.int32))
        trng = np.random.default_rng(tex_seed)
        x0, y0 = np.min([p.min(axis=0) for p in polys], axis=0)
        x1, y1 = np.max([p.max(axis=0) for p in polys], axis=0)
        x0, y0 = max(int(x0), 0), max(int(y0), 0)
        x1, y1 = min(int(x1), rgb.shape[1] - 1), min(int(y1), rgb.shape[0] - 1)
        if x1 <= x0 or y1 <= y0:
            continue
        box_mask = np.zeros(rgb.shape[:2], np.uint8)
        for k, p in enumerate(polys):
            cv2.fillPoly(box_mask, [p], 1 + k)
        h_, w_ = y1 - y0 + 1, x1 - x0 + 1
        # texture: colour, coarse noise, vertical stripes (windows, panel seams)
        noise = cv2.resize(trng.random((max(2, h_ // 12), max(2, w_ // 12))).astype(np.float32), (w_, h_))
        stripes = 0.5 + 0.5 * np.sin(np.arange(w_, dtype=np.float32) * 2 * math.pi / trng.uniform(6, 30))
        tex = colour[None, None, :] * (0.75 + 0.35 * noise[:, :, None]) * (0.85 + 0.15 * stripes[None, :, None])
        sub = box_mask[y0:y1 + 1, x0:x1 + 1]
        tex = np.where((sub == 2)[:, :, None], tex * 0.7, tex)  # the side face is darker
        region = out[y0:y1 + 1, x0:x1 + 1]
        region[sub > 0] = np.clip(tex[sub > 0], 0, 255).astype(np.uint8)
        mask |= (box_mask > 0).astype(np.uint8)
    return out, mask.astype(bool)
