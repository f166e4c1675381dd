"""Real ground/aerial pairs: street-level images beside a north-up aerial of the same place, the camera's position
in the aerial known (the format of `../shared/data/real_pairs/README.md`, one `pairs.json` per set).

A set's ground images are either equirectangular panoramas, from which pinhole front views are cut at any compass
heading and field of view (`pinhole_view`), or pinhole frames with their intrinsics and heading. Compass bearings
are degrees clockwise from north; the aerial is north-up, pixel (x right, y down), `m_per_px` metres a pixel.
Nothing here knows a matcher: `taco_mav.bench.real` scores a matcher on these.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.errors import DataError

__all__ = ["RealPair", "RealSet", "find_sets", "ground_bev", "load_set", "pinhole_view"]

GROUND_TYPES = ("panorama", "pinhole")


@dataclass(frozen=True)
class RealPair:
    """One place. ground / aerial / sky_mask: image paths; truth_px: the camera's position in the aerial, continuous
    pixels (x right, y down, top-left corner (0, 0)); heading_deg: pinhole sets only, the compass bearing it faces."""

    id: str
    ground: Path
    aerial: Path
    truth_px: tuple[float, float]
    sky_mask: Path | None = None
    heading_deg: float | None = None


@dataclass(frozen=True)
class RealSet:
    """A folder of pairs. ground: the `ground` block of pairs.json (type and geometry); camera_height_m: metres
    above the ground; m_per_px: the aerial's scale, metres a pixel; scale_uncertainty: its relative 1-sigma."""

    name: str
    folder: Path
    ground: dict[str, Any]
    camera_height_m: float
    m_per_px: float
    scale_uncertainty: float
    pairs: tuple[RealPair, ...]

    @property
    def is_panorama(self) -> bool:
        return self.ground["type"] == "panorama"


def _need(block: dict[str, Any], key: str, where: str, kind: type | tuple[type, ...] = (int, float)) -> Any:
    if not isinstance(block, dict) or key not in block:
        raise DataError(f"{where}: missing key {key!r}")
    value = block[key]
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise DataError(f"{where}: key {key!r} has {type(value).__name__} {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise DataError(f"{where}: key {key!r} is not finite")
    return value


def load_set(folder: Path) -> RealSet:
    """The set in `folder` (its pairs.json); DataError naming the file and key for anything missing or malformed,
    and for an image file that does not exist."""
    folder = Path(folder)
    path = folder / "pairs.json"
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"{folder}: no pairs.json (a set of real pairs needs one, see real_pairs/README.md)") from None
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read: {exc}") from exc
    where = str(path)
    ground = _need(meta, "ground", where, dict)
    kind = _need(ground, "type", f"{where} ground", str)
    if kind not in GROUND_TYPES:
        raise DataError(f"{where}: ground.type {kind!r} is not one of {', '.join(GROUND_TYPES)}")
    keys = (("width", "height", "col0_bearing_deg", "el_top_deg", "el_bottom_deg") if kind == "panorama"
            else ("width", "height", "fx", "fy", "cx", "cy", "pitch_deg"))
    for key in keys:
        _need(ground, key, f"{where} ground")
    if kind == "panorama":
        _need(ground, "clockwise", f"{where} ground", bool)
    aerial = _need(meta, "aerial", where, dict)
    if not _need(aerial, "north_up", f"{where} aerial", bool):
        raise DataError(f"{where}: aerial.north_up is false; only north-up aerials are read")
    m_per_px = float(_need(aerial, "m_per_px", f"{where} aerial"))
    if m_per_px <= 0.0:
        raise DataError(f"{where}: aerial.m_per_px {m_per_px} must be positive")
    pairs = []
    for k, p in enumerate(_need(meta, "pairs", where, list)):
        pw = f"{where} pairs[{k}]"
        files = {}
        for key in ("ground", "aerial") + (("sky_mask",) if isinstance(p, dict) and "sky_mask" in p else ()):
            f = folder / _need(p, key, pw, str)
            if not f.is_file():
                raise DataError(f"{pw}: {key} file {f} does not exist")
            files[key] = f
        truth = _need(p, "truth_px", pw, list)
        if len(truth) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in truth):
            raise DataError(f"{pw}: truth_px must be two finite numbers, got {truth!r}")
        heading = float(_need(p, "heading_deg", pw)) if kind == "pinhole" else None
        pairs.append(RealPair(str(p.get("id", k)), files["ground"], files["aerial"], (float(truth[0]),
                              float(truth[1])), files.get("sky_mask"), heading))
    if not pairs:
        raise DataError(f"{where}: no pairs")
    return RealSet(str(meta.get("set", folder.name)), folder, ground, float(_need(meta, "camera_height_m", where)),
                   m_per_px, float(aerial.get("m_per_px_uncertainty", 0.0)), tuple(pairs))


def find_sets(root: Path) -> list[RealSet]:
    """Every set under `root`: root itself when it holds pairs.json, else each sub-folder that does (sorted by
    name). DataError when there is none."""
    root = Path(root)
    if not root.is_dir():
        raise DataError(f"{root}: not a folder of real pairs")
    if (root / "pairs.json").is_file():
        return [load_set(root)]
    sets = [load_set(d) for d in sorted(root.iterdir()) if (d / "pairs.json").is_file()]
    if not sets:
        raise DataError(f"{root}: no set (no pairs.json in it or its sub-folders)")
    return sets


def read_rgb(path: Path) -> np.ndarray:
    """An image file as uint8 RGB (H, W, 3); DataError when it cannot be decoded."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise DataError(f"{path}: not a readable image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def pinhole_view(pano: np.ndarray, ground: dict[str, Any], bearing_deg: float, fov_deg: float, width: int,
                 height: int, pitch_deg: float, camera_height_m: float) -> tuple[np.ndarray, GroundCamera]:
    """A front view cut from an equirectangular panorama (H, W[, C]) described by the set's `ground` block: a
    pinhole of horizontal field of view `fov_deg`, `width` x `height` px, facing compass `bearing_deg`, pitched
    `pitch_deg` down, and its flat-ground camera model (`camera_height_m` above the ground). Bilinear, the
    panorama wrapping round at its seam."""
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    x, y = (u - cx) / f, (v - cy) / f  # camera ray (x right, y down, z = 1 forward)
    p = math.radians(pitch_deg)
    fwd = math.cos(p) - y * math.sin(p)  # along the horizontal heading
    up = -math.sin(p) - y * math.cos(p)
    right = x
    bearing = bearing_deg + np.degrees(np.arctan2(right, fwd))
    elev = np.degrees(np.arctan2(up, np.hypot(right, fwd)))
    view = _sample_panorama(pano, ground, bearing, elev)
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    return view, GroundCamera(K, int(width), int(height), float(camera_height_m), p)


def ground_bev(pano: np.ndarray, ground: dict[str, Any], camera_height_m: float, m_per_px: float, size_px: int,
               offset_px: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground of an equirectangular panorama (`ground` block) projected onto a north-up bird's-eye view of
    size_px x size_px at m_per_px, flat ground `camera_height_m` below the camera: (image (size_px, size_px[, C]),
    range_m, bearing_deg), the last two per pixel (compass, clockwise from north). The camera stands at the
    continuous pixel position (size_px / 2, size_px / 2) + offset_px (x right, y down, top-left corner (0, 0)), as
    an aerial's `truth_px` places it. Bilinear, the panorama wrapping round at its seam; whatever stands on the
    ground is smeared over it, as in any inverse perspective mapping."""
    c = size_px / 2.0
    y, x = np.mgrid[0:size_px, 0:size_px].astype(np.float64)
    east = (x + 0.5 - c - offset_px[0]) * m_per_px
    north = -(y + 0.5 - c - offset_px[1]) * m_per_px
    rng = np.maximum(np.hypot(east, north), 1e-6)
    bearing = np.mod(np.degrees(np.arctan2(east, north)), 360.0)
    elev = -np.degrees(np.arctan2(camera_height_m, rng))
    return _sample_panorama(pano, ground, bearing, elev), rng, bearing


def _sample_panorama(pano: np.ndarray, ground: dict[str, Any], bearing_deg: np.ndarray,
                     elev_deg: np.ndarray) -> np.ndarray:
    """The panorama (`ground` block) sampled bilinearly at compass bearings and elevations (deg, arrays of one
    shape), wrapping round at its seam."""
    H, W = pano.shape[:2]
    col0 = float(ground["col0_bearing_deg"])
    turn = (bearing_deg - col0) if ground["clockwise"] else (col0 - bearing_deg)
    map_x = np.mod(turn, 360.0) / 360.0 * W - 0.5 + 1.0  # +1: the wrapped column padded on the left
    el_top, el_bottom = float(ground["el_top_deg"]), float(ground["el_bottom_deg"])
    map_y = (elev_deg - el_top) / (el_bottom - el_top) * H - 0.5
    padded = np.concatenate([pano[:, -1:], pano, pano[:, :1]], axis=1)
    return cv2.remap(padded, map_x.astype(np.float32), map_y.astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
