#!/usr/bin/env python3
"""Build a UTM GeoTIFF mosaic from a local cache of XYZ slippy-map tiles ({z}/{x}/{y}.png|jpg).

    python tools/build_mosaic.py --tiles DIR --zoom 19 --bbox LAT0,LON0,LAT1,LON1 --out FILE.tif [--m-per-px M]

The tiles covering the bbox are stitched in Web Mercator (EPSG:3857, 256 px tiles, y down from the north) into
an in-memory RGBA raster (missing tiles are transparent), then reprojected with rasterio.warp (bilinear) into the
UTM zone of the bbox centre, at M m/px (default: the tiles' ground resolution at that latitude, ~0.2 m/px at
zoom 19 in Karlsruhe). The output is a tiled, deflate-compressed RGBA GeoTIFF whose alpha marks real imagery;
`taco_mav.cvgl.satellite.SatelliteMap` reads it directly. Downloading tiles is not this tool's job.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

import cv2
import numpy as np
import rasterio
from pyproj import Transformer
from pyproj.aoi import AreaOfInterest
from pyproj.database import query_utm_crs_info
from rasterio.warp import Resampling, reproject

log = logging.getLogger("build_mosaic")

HALF_WORLD_M = 20037508.342789244  # half the Web Mercator world width, metres
TILE_PX = 256


def tile_xy(lat: float, lon: float, zoom: int) -> tuple[float, float]:
    """Fractional XYZ tile coordinates (x east, y south) of a WGS84 point."""
    n = 2 ** zoom
    x = (lon + 180.0) / 360.0 * n
    y = (1.0 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2.0 * n
    return x, y


def utm_epsg(lat: float, lon: float) -> int:
    """EPSG code of the WGS84 UTM zone containing the point."""
    info = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(lon, lat, lon, lat))
    return int(info[0].code)


def _read_tile(folder: Path, zoom: int, x: int, y: int) -> np.ndarray | None:
    for ext in ("png", "jpg", "jpeg"):
        path = folder / str(zoom) / str(x) / f"{y}.{ext}"
        if path.is_file():
            img = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if img is None or img.shape[:2] != (TILE_PX, TILE_PX):
                raise SystemExit(f"{path}: not a {TILE_PX}x{TILE_PX} image")
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return None


def build_mosaic(tiles: Path, zoom: int, bbox: tuple[float, float, float, float], out: Path,
                 m_per_px: float | None = None) -> Path:
    """Stitch and reproject; bbox = (lat0, lon0, lat1, lon1) in degrees (any corner order). Returns out."""
    lat0, lon0, lat1, lon1 = bbox
    south, north, west, east = min(lat0, lat1), max(lat0, lat1), min(lon0, lon1), max(lon0, lon1)
    fx0, fy0 = tile_xy(north, west, zoom)
    fx1, fy1 = tile_xy(south, east, zoom)
    x0, y0, x1, y1 = int(math.floor(fx0)), int(math.floor(fy0)), int(math.floor(fx1)), int(math.floor(fy1))
    nx, ny = x1 - x0 + 1, y1 - y0 + 1
    if nx * ny > 40_000:
        raise SystemExit(f"bbox spans {nx}x{ny} tiles at zoom {zoom}; split it")
    src = np.zeros((4, ny * TILE_PX, nx * TILE_PX), np.uint8)
    found = 0
    for ty in range(ny):
        for tx in range(nx):
            tile = _read_tile(tiles, zoom, x0 + tx, y0 + ty)
            if tile is not None:
                rows, cols = slice(ty * TILE_PX, (ty + 1) * TILE_PX), slice(tx * TILE_PX, (tx + 1) * TILE_PX)
                src[:3, rows, cols] = tile.transpose(2, 0, 1)
                src[3, rows, cols] = 255
                found += 1
    if found == 0:
        raise SystemExit(f"{tiles}: no tiles {zoom}/{x0}..{x1}/{y0}..{y1}.png|jpg found")
    log.info("stitched %d of %d tiles", found, nx * ny)
    tile_m = 2 * HALF_WORLD_M / 2 ** zoom
    src_tr = rasterio.Affine(tile_m / TILE_PX, 0.0, -HALF_WORLD_M + x0 * tile_m,
                             0.0, -tile_m / TILE_PX, HALF_WORLD_M - y0 * tile_m)
    epsg = utm_epsg(0.5 * (south + north), 0.5 * (west + east))
    if m_per_px is None:
        m_per_px = tile_m / TILE_PX * math.cos(math.radians(0.5 * (south + north)))
    to_utm = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    lons, lats = np.meshgrid(np.linspace(west, east, 9), np.linspace(south, north, 9))
    E, N = to_utm.transform(lons.ravel(), lats.ravel())
    e0, n1 = math.floor(min(E) / m_per_px) * m_per_px, math.ceil(max(N) / m_per_px) * m_per_px
    width = int(math.ceil((max(E) - e0) / m_per_px))
    height = int(math.ceil((n1 - min(N)) / m_per_px))
    dst_tr = rasterio.Affine(m_per_px, 0.0, e0, 0.0, -m_per_px, n1)
    dst = np.zeros((4, height, width), np.uint8)
    reproject(src, dst, src_transform=src_tr, src_crs="EPSG:3857", dst_transform=dst_tr, dst_crs=f"EPSG:{epsg}",
              resampling=Resampling.bilinear)
    out.parent.mkdir(parents=True, exist_ok=True)
    profile = dict(driver="GTiff", width=width, height=height, count=4, dtype="uint8", crs=f"EPSG:{epsg}",
                   transform=dst_tr, photometric="RGB", compress="deflate", tiled=True, blockxsize=256,
                   blockysize=256)
    with rasterio.open(out, "w", **profile) as ds:
        ds.write(dst)
        ds.colorinterp = [rasterio.enums.ColorInterp.red, rasterio.enums.ColorInterp.green,
                          rasterio.enums.ColorInterp.blue, rasterio.enums.ColorInterp.alpha]
    log.info("wrote %s: %dx%d px at %.3f m/px, EPSG:%d", out, width, height, m_per_px, epsg)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tiles", type=Path, required=True, help="folder holding {z}/{x}/{y}.png|jpg tiles")
    parser.add_argument("--zoom", type=int, default=19)
    parser.add_argument("--bbox", required=True, help="LAT0,LON0,LAT1,LON1 in degrees")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--m-per-px", type=float, default=None, help="output resolution (default: native)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        bbox = tuple(float(v) for v in args.bbox.split(","))
    except ValueError:
        bbox = ()
    if len(bbox) != 4:
        parser.error(f"--bbox: expected LAT0,LON0,LAT1,LON1, got {args.bbox!r}")
    build_mosaic(args.tiles, args.zoom, bbox, args.out, args.m_per_px)  # type: ignore[arg-type]
    return 0


if __name__ == "__main__":
    sys.exit(main())
