"""Satellite mosaic service: heading-up crops of a north-up UTM GeoTIFF (paper Sec. III-C).

Frames and units:
- the mosaic is a north-up GeoTIFF in a UTM CRS (EPSG 326xx north / 327xx south); E, N are absolute UTM metres.
  Other CRSs are refused with a `MapError` naming the file and its CRS: reprojecting every crop would be slow and
  silently resample twice, so reproject the mosaic once instead (`taco-mav map` writes UTM).
- mosaic pixel coordinates (col, row) follow OpenCV: pixel (i, j) has its centre at integer (i, j), so the pixel
  containing a point is (round(col), round(row)).
- a crop of S x S pixels at s m/px is heading-up: the query heading theta (ENU rad, 0 = east, CCW) points to
  image-up, i.e. the mosaic is rotated by h_img = pi/2 - theta. The crop centre is the image centre,
  c = (S - 1) / 2 in pixel coordinates. Crop pixel (u, v) lies at forward = (c - v) s, left = (c - u) s metres
  from the centre in the vehicle frame, i.e. at centre + forward (cos theta, sin theta) + left (-sin theta,
  cos theta) in ENU.

Every crop is ONE cv2.warpAffine (bilinear) from a window of the source: the whole mosaic when it fits in memory
(`in_memory_max_mb`), else a buffer assembled from an LRU cache of 256 x 256 blocks read with rasterio windows.
When the crop is coarser than the mosaic by 2x or more, a pre-shrunk (area-averaged) level is used so the
bilinear warp does not alias.

GDAL keeps every file block it decodes in a process-wide cache of up to 5 % of the RAM by default; a drive across a
large mosaic would grow a daemon's memory by every block it ever read, on top of this module's own cache of the
decoded pixels. Reads here cap GDAL's cache at `GDAL_CACHE_MB`.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rasterio
from rasterio.enums import MaskFlags, Resampling
from rasterio.windows import Window

from taco_mav.cvgl.base import Crop
from taco_mav.errors import MapError, OffMapError

log = logging.getLogger(__name__)

BLOCK = 256
# GDAL's block cache during reads here, MB: ten 512 x 512 RGB tiles of a tiled GeoTIFF (0.79 MB each; a 512 px
# crop's window spans at most 3 x 3), so the blocks cached here decode each tile about once. Every reader of a
# mosaic takes it, so no reader's cache grows by every file block it reads.
GDAL_CACHE_MB = 8


@dataclass(frozen=True)
class CropPlan:
    """Geometry of one heading-up crop (`SatelliteMap.crop_plan`). level: pyramid level (0 = the mosaic, k: shrunk
    2^k times); M: 2x3 affine, crop pixel (u, v, 1) -> level pixel (x, y) (pixel centres at integers); bbox:
    (x0, y0, x1, y1) level pixels the bilinear warp reads, half-open, unclipped; level_shape: (H, W);
    inside: bbox inside the level and every mosaic pixel valid (valid fraction 1 without looking); wholly_off:
    bbox wholly outside the level."""

    level: int
    M: np.ndarray
    bbox: tuple[int, int, int, int]
    level_shape: tuple[int, int]
    inside: bool
    wholly_off: bool


def _is_utm(epsg: int | None) -> bool:
    return epsg is not None and (32601 <= epsg <= 32660 or 32701 <= epsg <= 32760)


class SatelliteMap:
    """A UTM GeoTIFF mosaic serving heading-up crops. Thread-safe; use as a context manager or call close().

    path: the GeoTIFF (1 band grey, or 3+ bands RGB[A], uint8). min_valid: default share of on-map pixels below
    which `crop` raises OffMapError (0.9: a matcher copes with a thin blank margin, not with half a crop).
    in_memory_max_mb: decoded RGBA size up to which the mosaic is read whole at open. cache_blocks: LRU capacity
    in 256 px blocks (256 KB each) for larger mosaics: 64 (16 MB) holds a trigger's five 512 px crops at the
    mosaic's resolution (about 25 blocks) and those of the next few triggers along the drive.
    """

    def __init__(self, path: str | Path, min_valid: float = 0.9, in_memory_max_mb: float = 1024.0,
                 cache_blocks: int = 64) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise MapError(f"{self.path}: satellite GeoTIFF not found")
        try:
            with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB):
                self._ds = rasterio.open(self.path)
        except rasterio.errors.RasterioIOError as exc:
            raise MapError(f"{self.path}: cannot open as a GeoTIFF ({exc})") from None
        ds = self._ds
        self.epsg: int = ds.crs.to_epsg() if ds.crs is not None else None  # type: ignore[assignment]
        if not _is_utm(self.epsg):
            crs = ds.crs.to_string() if ds.crs is not None else "no CRS"
            ds.close()
            raise MapError(f"{self.path}: CRS is {crs}; a UTM CRS (EPSG:326xx or EPSG:327xx) is required "
                           "(reproject the mosaic once, e.g. with rio warp or gdalwarp -t_srs, or build it with "
                           "taco-mav map)")
        tr = ds.transform
        if abs(tr.b) > 1e-12 or abs(tr.d) > 1e-12 or tr.a <= 0 or tr.e >= 0:
            ds.close()
            raise MapError(f"{self.path}: the GeoTIFF is not north-up (transform {tuple(tr)[:6]})")
        if ds.dtypes[0] != "uint8":
            ds.close()
            raise MapError(f"{self.path}: pixel type {ds.dtypes[0]} is not supported (uint8 RGB expected)")
        self._tr = tr
        self.width, self.height = ds.width, ds.height
        self.min_valid = float(min_valid)
        self._bands = [1, 2, 3] if ds.count >= 3 else [1, 1, 1]
        self._lock = threading.Lock()
        # No nodata value, no alpha band, no mask: every pixel is valid and the mask need not be read.
        self._all_valid = all(f == [MaskFlags.all_valid] for f in ds.mask_flag_enums)
        self._levels: dict[int, np.ndarray] = {}
        self._blocks: OrderedDict[tuple[int, int, int], np.ndarray] = OrderedDict()
        self._cache_blocks = int(cache_blocks)
        self.in_memory = self.width * self.height * 4 / 1e6 <= in_memory_max_mb
        if self.in_memory:
            self._levels[0] = self._read(0, 0, self.width, self.height, self.width, self.height)
        log.info("opened %s: %dx%d px, %.3f m/px, EPSG:%d, %s", self.path, self.width, self.height,
                 self.m_per_px, self.epsg, "in memory" if self.in_memory else "block cache")

    # ---------------------------------------------------------------- properties and coordinates
    @property
    def m_per_px(self) -> float:
        """Mosaic resolution, metres per pixel (mean of the two axes)."""
        return 0.5 * (self._tr.a - self._tr.e)

    @property
    def bounds_utm(self) -> tuple[float, float, float, float]:
        """(E_min, N_min, E_max, N_max), absolute UTM metres, outer pixel edges."""
        b = self._ds.bounds
        return (b.left, b.bottom, b.right, b.top)

    def pixel_of(self, E: float | np.ndarray, N: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mosaic pixel coordinates (col, row) of UTM points (pixel centres at integers)."""
        col = (np.asarray(E, dtype=float) - self._tr.c) / self._tr.a - 0.5
        row = (np.asarray(N, dtype=float) - self._tr.f) / self._tr.e - 0.5
        return col, row

    @staticmethod
    def crop_to_world(crop: Crop, uv_px: np.ndarray) -> np.ndarray:
        """Absolute UTM (E, N) of crop pixel positions uv_px (N, 2) as (u=col, v=row); returns shape (N, 2)."""
        uv = np.atleast_2d(np.asarray(uv_px, dtype=float))
        c = (crop.image.shape[0] - 1) / 2.0
        fwd = (c - uv[:, 1]) * crop.m_per_px
        left = (c - uv[:, 0]) * crop.m_per_px
        ct, st = math.cos(crop.heading), math.sin(crop.heading)
        return np.c_[crop.centre_utm[0] + fwd * ct - left * st, crop.centre_utm[1] + fwd * st + left * ct]

    # ---------------------------------------------------------------- crops
    def crop(self, centre_utm: np.ndarray, heading: float, size_px: int, m_per_px: float,
             min_valid: float | None = None) -> Crop:
        """Heading-up crop (S, S, 3) uint8 centred on centre_utm (absolute UTM metres, (2,)), heading ENU rad.

        Off-map pixels are zero. Raises OffMapError(valid_fraction) when the crop is wholly outside the mosaic or
        its on-map share is below `min_valid` (default: the map's).
        """
        min_valid = self.min_valid if min_valid is None else min_valid
        S = int(size_px)
        E0, N0 = float(centre_utm[0]), float(centre_utm[1])
        plan = self.crop_plan(centre_utm, heading, S, m_per_px)
        level, M, (x0, y0, x1, y1) = plan.level, plan.M.copy(), plan.bbox
        H, W = plan.level_shape
        if plan.wholly_off:
            raise self.off_map_error(E0, N0, 0.0, min_valid, wholly=True)
        x0c, y0c, x1c, y1c = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        window = self._window(level, x0c, y0c, x1c, y1c)
        M[0, 2] -= x0c
        M[1, 2] -= y0c
        out = cv2.warpAffine(window, M, (S, S), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
        valid = 1.0 if plan.inside else float(cv2.mean(out)[3] / 255.0)
        if valid < min_valid or valid <= 0.0:
            raise self.off_map_error(E0, N0, valid, min_valid)
        rgb = cv2.cvtColor(out, cv2.COLOR_RGBA2RGB)  # a fast contiguous copy of the colour channels
        if valid < 1.0:
            rgb[out[:, :, 3] < 128] = 0
        return Crop(image=rgb, centre_utm=np.array([E0, N0]), heading=float(heading), m_per_px=float(m_per_px),
                    valid_fraction=valid)

    def crop_plan(self, centre_utm: np.ndarray, heading: float, size_px: int, m_per_px: float) -> CropPlan:
        """The geometry of `crop` without the pixels: the pyramid level, the affine M taking crop pixel (u, v, 1)
        to that level's pixel (x, y), the level pixel box the bilinear warp reads (unclipped, with a 2 px margin)
        and whether it lies wholly inside / wholly outside the level. `crop` and the device crops
        (taco_mav/cvgl/fg2/device_crops.py) both warp with it. MapError for a non-finite centre or heading."""
        S = int(size_px)
        E0, N0 = float(centre_utm[0]), float(centre_utm[1])
        if not (math.isfinite(E0) and math.isfinite(N0) and math.isfinite(heading)):
            raise MapError(f"{self.path}: crop request with a non-finite centre/heading ({E0}, {N0}, {heading})")
        level = max(0, int(math.floor(math.log2(max(m_per_px / self.m_per_px, 1.0)))))
        src, sx, sy = self._level_geometry(level)
        # Affine map crop (u, v) -> level pixel (x, y): u, v -> ENU -> level-0 pixel -> level pixel.
        c = (S - 1) / 2.0
        ct, st = math.cos(heading), math.sin(heading)
        # E = E0 + s(c - v) ct - s(c - u) st ; N = N0 + s(c - v) st + s(c - u) ct
        s = m_per_px
        A_en = np.array([[s * st, -s * ct, E0 + s * c * (ct - st)],
                         [-s * ct, -s * st, N0 + s * c * (st + ct)]])
        tr = self._tr
        A_px0 = np.array([[1.0 / tr.a, 0.0, -tr.c / tr.a - 0.5], [0.0, 1.0 / tr.e, -tr.f / tr.e - 0.5]])
        A_lvl = np.array([[1.0 / sx, 0.0, 0.5 / sx - 0.5], [0.0, 1.0 / sy, 0.5 / sy - 0.5]])
        M = _compose(A_lvl, _compose(A_px0, A_en))
        corners = np.array([[-0.5, -0.5, 1.0], [S - 0.5, -0.5, 1.0], [-0.5, S - 0.5, 1.0], [S - 0.5, S - 0.5, 1.0]])
        xy = corners @ M.T
        x0, y0 = int(math.floor(xy[:, 0].min())) - 2, int(math.floor(xy[:, 1].min())) - 2
        x1, y1 = int(math.ceil(xy[:, 0].max())) + 3, int(math.ceil(xy[:, 1].max())) + 3
        H, W = src
        wholly_off = x1 <= 0 or y1 <= 0 or x0 >= W or y0 >= H
        inside = self._all_valid and x0 >= 0 and y0 >= 0 and x1 <= W and y1 <= H
        return CropPlan(level, M, (x0, y0, x1, y1), (H, W), inside, wholly_off)

    def off_map_error(self, E0: float, N0: float, valid: float, min_valid: float,
                      wholly: bool = False) -> OffMapError:
        """The OffMapError `crop` raises for a crop at (E0, N0): wholly outside the mosaic, or with on-map share
        `valid` below min_valid."""
        if wholly:
            return OffMapError(f"{self.path}: crop at E={E0:.1f} N={N0:.1f} is wholly outside the mosaic "
                               f"{tuple(round(b, 1) for b in self.bounds_utm)}", 0.0)
        return OffMapError(f"{self.path}: crop at E={E0:.1f} N={N0:.1f} is {100 * (1 - valid):.1f} % off the "
                           f"mosaic (at least {100 * min_valid:.1f} % on-map required)", valid)

    def level_rgba(self, level: int) -> np.ndarray | None:
        """The whole pyramid level as (H, W, 4) RGBA uint8 when the mosaic is in memory (built on first use, as
        `crop` builds it), else None (block-cache mosaics: use `window_rgba`). Do not write to it."""
        if not self.in_memory:
            return None
        self._window(level, 0, 0, 1, 1)  # builds the level on first use
        with self._lock:
            return self._levels[level]

    def window_rgba(self, level: int, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """RGBA uint8 pixels of a level for [x0, x1) x [y0, y1), which must lie inside the level (a view into
        the in-memory level, or a buffer assembled from the block cache). Do not write to it."""
        return self._window(level, x0, y0, x1, y1)

    # ---------------------------------------------------------------- pixel access
    def _level_geometry(self, level: int) -> tuple[tuple[int, int], float, float]:
        """(H, W) of a pyramid level and its scale factors (level-0 pixels per level pixel) along x, y."""
        f = 2 ** level
        W, H = max(1, -(-self.width // f)), max(1, -(-self.height // f))
        return (H, W), self.width / W, self.height / H

    def _read(self, col0: int, row0: int, col1: int, row1: int, out_w: int, out_h: int) -> np.ndarray:
        """Read level-0 window [col0, col1) x [row0, row1) resampled to (out_h, out_w, 4) RGBA uint8."""
        win = Window(col0, row0, col1 - col0, row1 - row0)
        resampling = Resampling.average if (out_w, out_h) != (col1 - col0, row1 - row0) else Resampling.nearest
        with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB):
            rgb = self._ds.read(self._bands, window=win, out_shape=(3, out_h, out_w), resampling=resampling)
            if self._all_valid:
                mask = np.full((out_h, out_w), 255, np.uint8)
            else:
                mask = self._ds.dataset_mask(window=win, out_shape=(out_h, out_w), resampling=resampling)
        return cv2.merge([rgb[0], rgb[1], rgb[2], mask])

    def _window(self, level: int, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """RGBA pixels of a level for [x0, x1) x [y0, y1) (inside the level's extent)."""
        if self.in_memory:
            with self._lock:
                if level not in self._levels:
                    (H, W), _, _ = self._level_geometry(level)
                    self._levels[level] = cv2.resize(self._levels[0], (W, H), interpolation=cv2.INTER_AREA)
                arr = self._levels[level]
            return arr[y0:y1, x0:x1]
        buf = np.zeros((y1 - y0, x1 - x0, 4), np.uint8)
        for by in range(y0 // BLOCK, (y1 - 1) // BLOCK + 1):
            for bx in range(x0 // BLOCK, (x1 - 1) // BLOCK + 1):
                blk = self._block(level, bx, by)
                gx0, gy0 = bx * BLOCK, by * BLOCK
                sx0, sy0 = max(x0, gx0), max(y0, gy0)
                sx1, sy1 = min(x1, gx0 + blk.shape[1]), min(y1, gy0 + blk.shape[0])
                if sx1 > sx0 and sy1 > sy0:
                    buf[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = blk[sy0 - gy0:sy1 - gy0, sx0 - gx0:sx1 - gx0]
        return buf

    def _block(self, level: int, bx: int, by: int) -> np.ndarray:
        """One cached BLOCK x BLOCK tile of a level (smaller at the right/bottom edges)."""
        key = (level, bx, by)
        with self._lock:
            blk = self._blocks.get(key)
            if blk is not None:
                self._blocks.move_to_end(key)
                return blk
            (H, W), sx, sy = self._level_geometry(level)
            w, h = min(BLOCK, W - bx * BLOCK), min(BLOCK, H - by * BLOCK)
            c0, r0 = int(round(bx * BLOCK * sx)), int(round(by * BLOCK * sy))
            c1, r1 = min(self.width, int(round((bx * BLOCK + w) * sx))), min(self.height, int(round((by * BLOCK + h) * sy)))
            blk = self._read(c0, r0, c1, r1, w, h)
            self._blocks[key] = blk
            while len(self._blocks) > self._cache_blocks:
                self._blocks.popitem(last=False)
            return blk

    def close(self) -> None:
        """Release the file handle and caches."""
        self._ds.close()
        self._levels.clear()
        self._blocks.clear()

    def __enter__(self) -> "SatelliteMap":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _compose(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """2x3 affine A after 2x3 affine B."""
    return A[:, :2] @ B + np.c_[np.zeros((2, 2)), A[:, 2]]
