"""The satellite mosaic: a canvas of flat colours and material labels, textured and written as a GeoTIFF.

Frames: local ENU metres (x east, y north) relative to the world centre, which sits at UTM (E_c, N_c). The
canvas is north-up; pixel (col, row) covers [E0 + col r, E0 + (col + 1) r) x (N0 - (row + 1) r, N0 - row r]
with r metres per pixel (the GeoTIFF's affine transform). Drawing uses OpenCV with 1/8-pixel fixed point and
anti-aliasing. Texture: each material has its own amplitude of per-pixel noise and of 1 m and 5 m blobs
(so a 0.2 m/px crop of any size has structure), under a 60 m illumination field and blurred cast shadows.
The GeoTIFF is RGB uint8, deflate-compressed, tiled, with no timestamps: the same seed gives the same bytes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import Affine
from rasterio.windows import Window

log = logging.getLogger(__name__)

__all__ = ["Material", "Canvas", "write_geotiff"]


class Material:
    """Material labels of the canvas (uint8)."""

    GRASS, SOIL, PAVEMENT, ASPHALT, MARKING, ROOF, TREE, CAR, PATH, YARD = range(10)


# Per-material texture amplitudes (relative brightness): per-pixel, 1 m blobs, 5 m blobs.
_FINE = np.array([0.10, 0.10, 0.05, 0.07, 0.03, 0.04, 0.16, 0.03, 0.08, 0.06], np.float32)
_MID = np.array([0.10, 0.10, 0.04, 0.06, 0.04, 0.03, 0.18, 0.02, 0.06, 0.06], np.float32)
_LARGE = np.array([0.14, 0.12, 0.05, 0.07, 0.03, 0.04, 0.08, 0.00, 0.06, 0.08], np.float32)


@dataclass
class Canvas:
    """A drawable north-up raster. x0, y1: local metres of the top-left pixel corner; m_per_px: metres per
    pixel; img: (H, W, 3) uint8 RGB; mat: (H, W) uint8 Material labels; shadow: (H, W) uint8 shadow mask."""

    x0: float
    y1: float
    m_per_px: float
    img: np.ndarray
    mat: np.ndarray
    shadow: np.ndarray

    @classmethod
    def blank(cls, x0: float, y1: float, width: int, height: int, m_per_px: float) -> "Canvas":
        return cls(x0, y1, m_per_px, np.zeros((height, width, 3), np.uint8), np.zeros((height, width), np.uint8),
                   np.zeros((height, width), np.uint8))

    @property
    def shape(self) -> tuple[int, int]:
        return self.img.shape[:2]

    def px(self, xy: np.ndarray) -> np.ndarray:
        """Local metres (..., 2) -> OpenCV fixed-point pixel coordinates (shift 3), int32."""
        xy = np.asarray(xy, dtype=np.float64)
        col = (xy[..., 0] - self.x0) / self.m_per_px - 0.5
        row = (self.y1 - xy[..., 1]) / self.m_per_px - 0.5
        return np.round(np.stack([col, row], axis=-1) * 8.0).astype(np.int32)

    def poly(self, polys: list[np.ndarray] | np.ndarray, colour, mat: int | None) -> None:
        """Fill polygons given in local metres (each (K, 2))."""
        pts = [self.px(p) for p in (polys if isinstance(polys, list) else [polys])]
        cv2.fillPoly(self.img, pts, tuple(float(c) for c in colour), cv2.LINE_AA, shift=3)
        if mat is not None:
            cv2.fillPoly(self.mat, pts, int(mat), cv2.LINE_8, shift=3)

    def line(self, lines: list[np.ndarray], width_m: float, colour, mat: int | None) -> None:
        """Draw open polylines (each (K, 2) local metres) `width_m` metres wide (at least one pixel)."""
        if not lines:
            return
        pts = [self.px(p) for p in lines]
        th = max(1, int(round(width_m / self.m_per_px)))
        cv2.polylines(self.img, pts, False, tuple(float(c) for c in colour), th, cv2.LINE_AA, shift=3)
        if mat is not None:
            cv2.polylines(self.mat, pts, False, int(mat), th, cv2.LINE_8, shift=3)

    def circle(self, centre: np.ndarray, radius_m: float, colour, mat: int | None, target: np.ndarray | None = None) -> None:
        """Fill a disc (centre local metres); `target` draws into another (H, W) mask instead of img/mat."""
        c = tuple(int(v) for v in self.px(centre))
        r = int(round(radius_m / self.m_per_px * 8.0))
        if target is not None:
            cv2.circle(target, c, r, colour, -1, cv2.LINE_8, shift=3)
            return
        cv2.circle(self.img, c, r, tuple(float(v) for v in colour), -1, cv2.LINE_AA, shift=3)
        if mat is not None:
            cv2.circle(self.mat, c, r, int(mat), -1, cv2.LINE_8, shift=3)

    def roi_local(self, centre: np.ndarray, half_m: float) -> tuple[slice, slice, np.ndarray, np.ndarray] | None:
        """Pixel slices of a square around `centre` and the local metres (X, Y) of those pixel centres."""
        h, w = self.shape
        c = (centre[0] - self.x0) / self.m_per_px
        r = (self.y1 - centre[1]) / self.m_per_px
        k = half_m / self.m_per_px
        c0, c1 = max(int(c - k), 0), min(int(c + k) + 1, w)
        r0, r1 = max(int(r - k), 0), min(int(r + k) + 1, h)
        if c0 >= c1 or r0 >= r1:
            return None
        X = self.x0 + (np.arange(c0, c1) + 0.5) * self.m_per_px
        Y = self.y1 - (np.arange(r0, r1) + 0.5) * self.m_per_px
        XX, YY = np.meshgrid(X, Y)
        return slice(r0, r1), slice(c0, c1), XX, YY


def _upsample(grid: np.ndarray, cell_px: float, row0: int, rows: int, width: int) -> np.ndarray:
    """Rows [row0, row0 + rows) of `grid` stretched by `cell_px` (bicubic, continuous across strips)."""
    M = np.array([[1.0 / cell_px, 0.0, 0.5 / cell_px + 0.5], [0.0, 1.0 / cell_px, (row0 + 0.5) / cell_px + 0.5]])
    return cv2.warpAffine(grid, M, (width, rows), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REFLECT)


def write_geotiff(canvas: Canvas, path: Path, epsg: int, origin_utm: tuple[float, float], seed: int,
                  progress: bool = False, strip_rows: int = 1024) -> Affine:
    """Texture `canvas` and write it as an RGB uint8 GeoTIFF at `path`; returns its affine transform.

    origin_utm: UTM (E, N) metres of the local origin (the world centre); epsg: the UTM zone's EPSG code.
    The output is a pure function of (canvas, seed): strips draw their per-pixel noise from
    SeedSequence([seed, 7, strip]); blob fields are drawn once and resampled per strip.
    """
    from tqdm import tqdm

    h, w = canvas.shape
    res = canvas.m_per_px
    transform = Affine(res, 0.0, origin_utm[0] + canvas.x0, 0.0, -res, origin_utm[1] + canvas.y1)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    cells = {k: max(1.0, v / res) for k, v in (("mid", 1.0), ("large", 5.0), ("light", 60.0))}
    grids = {k: rng.standard_normal((int(h / c) + 4, int(w / c) + 4)).astype(np.float32) for k, c in cells.items()}
    base = cv2.GaussianBlur(canvas.img, (0, 0), 0.5)
    shade = cv2.GaussianBlur(canvas.shadow, (0, 0), 0.8 / res * 0.5)
    profile = dict(driver="GTiff", width=w, height=h, count=3, dtype="uint8", crs=CRS.from_epsg(epsg),
                   transform=transform, compress="deflate", predictor=2, tiled=True, blockxsize=512,
                   blockysize=512, photometric="RGB", interleave="pixel")
    path = Path(path)
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path, "w", **profile) as dst:
        starts = range(0, h, strip_rows)
        for i, r0 in enumerate(tqdm(starts, desc="mosaic", unit="strip", disable=not progress, leave=False)):
            rows = min(strip_rows, h - r0)
            srng = np.random.default_rng(np.random.SeedSequence([seed, 7, i]))
            mat = canvas.mat[r0 : r0 + rows]
            gain = 1.0 + _FINE[mat] * srng.standard_normal((rows, w), dtype=np.float32)
            gain += _MID[mat] * _upsample(grids["mid"], cells["mid"], r0, rows, w)
            gain += _LARGE[mat] * _upsample(grids["large"], cells["large"], r0, rows, w)
            gain *= 1.0 + 0.05 * _upsample(grids["light"], cells["light"], r0, rows, w)
            gain *= 1.0 - 0.55 * shade[r0 : r0 + rows].astype(np.float32) / 255.0
            out = base[r0 : r0 + rows].astype(np.float32) * gain[:, :, None]
            out = np.clip(out + 0.5, 0, 255).astype(np.uint8)
            dst.write(np.ascontiguousarray(out.transpose(2, 0, 1)), window=Window(0, r0, w, rows))
    aux = path.with_name(path.name + ".aux.xml")
    if aux.exists():
        aux.unlink()
    log.info("mosaic %s: %d x %d px at %.2f m/px", path.name, w, h, res)
    return transform
