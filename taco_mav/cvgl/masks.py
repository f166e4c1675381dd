"""Masks for what inverse perspective mapping cannot represent, found in the camera image.

IPM assumes every pixel below the horizon shows flat ground. It is wrong for
- the sky and anything at or above the horizon: `BevProjector` already drops rays that do not hit the ground
  within `max_range_m` (its `mask`);
- the ego vehicle: a bonnet or mount in the bottom rows of the frame (`ego_rows`, from the profile: the camera's
  mounting is known, not guessed per frame);
- vertical structure: poles, trunks, parked and moving cars, facades. Their pixels are mapped onto the ground
  behind their foot and smeared radially; a satellite sees their roofs or nothing there.

Vertical structure is found from one image cue: long, straight, image-vertical edges. A vertical world edge
projects to an image-vertical line (pitch within a few degrees, no roll), while a straight ground line at
lateral offset y projects to a line through the vanishing point with slope du/dv = -y / h (h the mount
height): it is within `max_tilt_deg` of vertical only in a narrow cone below the vanishing point (|y| < 0.3 m
for 10 deg and h = 1.65 m), which is excluded. Each column that holds such an edge is masked from the edge's
lowest pixel (the object's foot) up (a stixel: everything above an object's foot in its column is object or
sky, never ground nearer than the foot); the columns between two such columns whose feet are on nearly the same row
are masked down to the higher foot, as one object's face (two poles at the same distance either side of the
road also mask the ground beyond both).
A face with no vertical edge within `fill_frac` of the image width is not found; nor is an object in the excluded cone.
Moving objects are masked only as vertical structure: a single frame cannot tell parked from moving.

Frames and units: camera pixels (u, v) = (column, row), OpenCV convention; images uint8 or float (H, W[, 3]).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera

__all__ = ["MaskOptions", "horizon_row", "vertical_structure_mask", "vegetation_mask", "image_mask"]

# `_gradient_bands`'s bands: rows per band, and the rows read beyond each side (blur radius 2 + Sobel radius 1).
_BAND_ROWS = 64
_HALO = 3


@dataclass(frozen=True)
class MaskOptions:
    """vertical: find and mask vertical structure; ego_rows: bottom image rows hidden by the ego vehicle;
    max_tilt_deg: how far from image-vertical an edge may lean; min_len_frac: shortest edge kept, as a share of
    the image height; min_contrast: least gradient (grey levels per pixel) of an edge; an edge continues down through
    edges of a third of that; fill_frac, foot_tol_frac: the columns between two object
    columns at most fill_frac of the image width apart whose feet are within foot_tol_frac of the image height
    (one object's edges) are masked down to the higher foot (its face); dilate_px: final growth; min_view_fraction: a
    trigger whose masks leave less than this share of the unmasked template gives no answer (w at its floor);
    vegetation: find and mask standing vegetation by colour (`vegetation_mask`), exg_min its least excess-green
    index, vegetation_tall_only: only vegetation that reaches the horizon (trees, hedges; not lawns and verges)."""

    vertical: bool = True
    ego_rows: int = 0
    max_tilt_deg: float = 10.0
    min_len_frac: float = 0.05
    min_contrast: float = 6.0
    fill_frac: float = 0.35
    foot_tol_frac: float = 0.04
    dilate_px: int = 3
    min_view_fraction: float = 0.25
    vegetation: bool = False
    exg_min: float = 0.05
    vegetation_tall_only: bool = True


def horizon_row(camera: GroundCamera) -> float:
    """Image row of the horizon (ground at infinity straight ahead; pitch down positive), unclipped."""
    return float(camera.K[1, 2] - camera.K[1, 1] * math.tan(camera.pitch_rad))


def vertical_structure_mask(image: np.ndarray, camera: GroundCamera, opts: MaskOptions = MaskOptions()) -> np.ndarray:
    """bool (H, W): pixels showing vertical structure (module docstring), True = not ground.

    The gradient is classified band by band (`_gradient_bands`) into the two edge maps the rest needs, uint8
    (H, W) each: a frame's float32 gradients and the cone's coordinates are never held whole (a 1280x720 frame's
    are 3.7 MB an array, about 25 MB at once, which would set the daemon's peak memory)."""
    H, W = image.shape[:2]
    tilt = math.tan(math.radians(opts.max_tilt_deg))
    # the cone below the vanishing point where straight ground lines are near-vertical too
    vh, cx = horizon_row(camera), float(camera.K[0, 2])
    u = np.arange(W, dtype=np.float32)[None, :]
    strong_edges = np.empty((H, W), np.uint8)  # vertical, outside the cone, at least min_contrast
    weak_edges = np.empty((H, W), np.uint8)  # the same at a third of it
    for r0, r1, gx, gy in _gradient_bands(image):
        agx = np.abs(gx, out=gx)  # in place: only the magnitudes are used
        vertical = np.abs(gy, out=gy) <= tilt * agx
        v = np.arange(r0, r1, dtype=np.float32)[:, None]
        vertical &= ~((v > vh) & (np.abs(u - cx) <= tilt * (v - vh) + 2.0))
        np.copyto(strong_edges[r0:r1], vertical & (agx >= opts.min_contrast))
        np.copyto(weak_edges[r0:r1], vertical & (agx >= opts.min_contrast / 3.0))
    L = max(5, int(round(opts.min_len_frac * H)))
    line = np.ones((L, 1), np.uint8)
    strong = cv2.morphologyEx(strong_edges, cv2.MORPH_OPEN, line)
    # hysteresis: weaker vertical edges continuing a strong one (an object's edge against ground is often
    # fainter than against the sky) extend it down to the object's foot
    weak = cv2.morphologyEx(weak_edges, cv2.MORPH_OPEN, line) | strong
    del strong_edges, weak_edges
    n, labels = cv2.connectedComponents(weak, connectivity=8)
    keep = np.zeros(n, bool)
    keep[np.unique(labels[strong > 0])] = True
    keep[0] = False
    runs = keep[labels]
    del labels
    has = runs.any(axis=0)
    out = np.zeros((H, W), np.uint8)
    if has.any():
        foot = np.where(has, H - 1 - np.argmax(runs[::-1], axis=0), -1)  # lowest edge pixel per column
        foot = _fill_between(foot, max(2, int(round(opts.fill_frac * W))), max(2.0, opts.foot_tol_frac * H))
        out = (np.arange(H)[:, None] <= foot[None, :]).astype(np.uint8)
        if opts.dilate_px > 0:
            d = 2 * opts.dilate_px + 1
            out = cv2.dilate(out, np.ones((d, d), np.uint8))
    return out.astype(bool)


def _gradient_bands(image: np.ndarray) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:
    """The image gradient band by band: (r0, r1, gx, gy) for rows [r0, r1), grey levels per pixel, float32
    (r1 - r0, W) each, after a Gaussian blur (sigma 1 px); for colour images that of the channel with the
    strongest gradient at each pixel (a magenta box on grey asphalt of the same brightness still has an edge).

    Bands of `_BAND_ROWS` rows, each read with `_HALO` rows either side (the 5x5 blur's 2 and the Sobel's 1), so
    a band's rows see exactly the pixels the whole image would give them (the same numbers bit for bit,
    tests/test_masks.py): a 1280x720 colour frame's float32 copy, blur, gradients and their squares whole held
    about 60 MB at once in the matcher thread, a band a 12th of it."""
    H = image.shape[0]
    for r0 in range(0, H, _BAND_ROWS):
        r1 = min(H, r0 + _BAND_ROWS)
        a, b = max(0, r0 - _HALO), min(H, r1 + _HALO)
        img = cv2.GaussianBlur(image[a:b].astype(np.float32), (5, 5), 1.0)
        planes = cv2.split(img) if img.ndim == 3 else [img]
        grads = [(cv2.Sobel(p, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)[r0 - a:r1 - a],
                  cv2.Sobel(p, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)[r0 - a:r1 - a]) for p in planes]
        yield (r0, r1, *_strongest_channel(grads))


def _strongest_channel(grads: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel gradients [(gx, gy), ...], each (rows, W), reduced to the (gx, gy) of the channel whose
    gradient is the largest at each pixel, the first of equal ones (what argmax over the channels picks; chosen
    by comparisons on contiguous planes, a third of the time of argmax and take_along_axis on interleaved ones)."""
    ox, oy = grads[0]
    if len(grads) == 1:
        return ox, oy
    ox, oy = ox.copy(), oy.copy()
    best = ox * ox
    best += oy * oy
    for gx, gy in grads[1:]:
        mag = gx * gx
        mag += gy * gy
        take = mag > best
        np.copyto(ox, gx, where=take)
        np.copyto(oy, gy, where=take)
        np.maximum(best, mag, out=best)
    return ox, oy


def _fill_between(foot: np.ndarray, max_gap: int, tol: float) -> np.ndarray:
    """Foot rows per column (-1: no object) with faces filled. Object columns form groups (runs with gaps of at
    most 2 columns), each with its lowest foot; the columns between two groups at most `max_gap` apart whose
    feet differ by at most `tol` rows (one object's edges) get the higher of the two feet."""
    foot = foot.copy()
    cols = np.flatnonzero(foot >= 0)
    if cols.size < 2:
        return foot
    breaks = np.flatnonzero(np.diff(cols) > 3)
    starts = np.r_[cols[0], cols[breaks + 1]]
    ends = np.r_[cols[breaks], cols[-1]]
    feet = [int(foot[a:b + 1].max()) for a, b in zip(starts, ends)]
    for k in range(len(starts) - 1):
        a, b = ends[k], starts[k + 1]
        if b - a <= max_gap + 1 and abs(feet[k] - feet[k + 1]) <= tol:
            gap = foot[a + 1:b]
            np.maximum(gap, min(feet[k], feet[k + 1]), out=gap)
    return foot


def vegetation_mask(image: np.ndarray, camera: GroundCamera, opts: MaskOptions = MaskOptions()) -> np.ndarray:
    """bool (H, W): standing vegetation found by colour, True = not ground. A pixel is green where its excess-green
    index 2g - r - b of chromaticities (r + g + b = 1) is at least `exg_min` (a 3x3 opening drops single pixels).
    With `vegetation_tall_only`, only green regions that reach above the horizon row are kept (trees and hedges
    stand up from the ground, a lawn or a verge lies on it and is ground the map shows), and each is masked as a
    stixel, from its lowest pixel per column up (what is above a tree's foot in its column is tree or beyond it).
    A grey image has no colour: nothing is masked."""
    H, W = image.shape[:2]
    if image.ndim != 3:
        return np.zeros((H, W), bool)
    f = image.astype(np.float32)
    tot = f.sum(axis=2) + 1.0
    exg = (2.0 * f[..., 1] - f[..., 0] - f[..., 2]) / tot
    green = ((exg >= opts.exg_min) & (tot > 30.0)).astype(np.uint8)
    green = cv2.morphologyEx(green, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    if not opts.vegetation_tall_only:
        return green.astype(bool)
    n, labels = cv2.connectedComponents(green, connectivity=8)
    if n <= 1:
        return np.zeros((H, W), bool)
    vh = max(0, int(math.floor(horizon_row(camera))))
    top = labels[: min(H, vh + 1)]
    keep = np.zeros(n, bool)
    keep[np.unique(top)] = True
    keep[0] = False
    tall = keep[labels]
    has = tall.any(axis=0)
    foot = np.where(has, H - 1 - np.argmax(tall[::-1], axis=0), -1)
    out = (np.arange(H)[:, None] <= foot[None, :]).astype(np.uint8)
    if opts.dilate_px > 0:
        d = 2 * opts.dilate_px + 1
        out = cv2.dilate(out, np.ones((d, d), np.uint8))
    return out.astype(bool)


def image_mask(image: np.ndarray, camera: GroundCamera, opts: MaskOptions = MaskOptions()) -> np.ndarray | None:
    """bool (H, W) of the pixels IPM must not use (vertical structure, ego vehicle), or None when none are."""
    m = vertical_structure_mask(image, camera, opts) if opts.vertical else None
    if opts.vegetation:
        v = vegetation_mask(image, camera, opts)
        m = v if m is None else (m | v)
    if opts.ego_rows > 0:
        m = np.zeros(image.shape[:2], bool) if m is None else m
        m[-int(opts.ego_rows):] = True
    return m if m is not None and m.any() else None
