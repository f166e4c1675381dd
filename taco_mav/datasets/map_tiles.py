"""A satellite map in one call: an XYZ, WMTS or WMS service -> the UTM GeoTIFF the daemon reads (`taco-mav map`).

Everything on the network goes through GDAL's WMS driver, read with rasterio: `map_sources` writes the service
description GDAL reads, and no tile is fetched here. GDAL does the requests (at most `connections` at a time, with
our User-Agent), keeps every tile it got in its disk cache (a re-run, or a run after an interruption, reads what
it has from there and asks only for the rest) and fills a tile the server has not got (HTTP 404 or 204) with
zeros, alpha 0. A rasterio WarpedVRT reprojects the service's pixels (bilinear) into the output grid, one window
of 1024 x 1024 output pixels at a time, behind the project's progress bar.

Frames and units:
- bbox: WGS84 degrees (LAT0,LON0,LAT1,LON1, any two opposite corners);
- the output: north-up, in the WGS84 UTM zone of the bbox centre (EPSG 326zz / 327zz), E, N in metres; its grid
  snapped to multiples of `m_per_px` (metres per pixel, the same east and north) and covering the whole bbox
  (its corners and edges projected into UTM).

The GeoTIFF is RGBA uint8 (alpha 255 where the service had imagery, 0 where it had none), tiled in 512 x 512
blocks, deflate-compressed, as the synthetic worlds write theirs, so that
`taco_mav.cvgl.satellite.SatelliteMap` reads it directly. Its size and that of the tiles it needs are estimated
before any request and compared with the free disk space.

What GDAL's WMS driver does not do (GDAL 3.10), and what stands in for it here:
- it does not retry a failed request (GDAL_HTTP_MAX_RETRY is not read by its parallel fetch): a window whose read
  failed on a dropped connection, a timeout, HTTP 408, 429 or 5xx is read again after a pause (`retries`); the
  tiles it had are in the cache and are not asked again;
- its error text carries the HTTP status and the block, not the URL (`map_sources.source_error` rebuilds it);
- it caches only images: a tile the server has not got (HTTP 404) is asked again on a re-run.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import rasterio
from rasterio.enums import Resampling
from rasterio.errors import RasterioIOError
from rasterio.transform import Affine
from rasterio.vrt import WarpedVRT
from rasterio.windows import Window

from taco_mav.datasets.map_sources import (DEFAULT_USER_AGENT, MAX_ZOOM, BBox, GdalHttp, MapSource, SourceKind,
                                           default_cache_dir, failure_place, ground_m_per_unit, parse_source,
                                           read_failure, service_xml, source_error, xyz_ground_m_per_px, xyz_tile)
from taco_mav.errors import MapSourceError, UsageError
from taco_mav.geo import UtmProjector
from taco_mav.progress import progress_bar

__all__ = ["MapResult", "build_map", "check_request"]

log = logging.getLogger(__name__)

BLOCK_PX = 512  # output GeoTIFF block, px (as the synthetic worlds' mosaics)
WINDOW_PX = 1024  # output pixels read per step (one progress step), a multiple of BLOCK_PX
# Disk needed, bytes per pixel: the GeoTIFF is at most its raw RGBA (deflate keeps aerial imagery at ~60-80 %);
# cached tiles ~0.2 (JPEG) to ~1.5 (PNG) per source pixel.
OUTPUT_BYTES_PER_PX = 4.0
CACHE_BYTES_PER_PX = 1.5


# ------------------------------------------------------------------------------------------------ geometry

def _zoom_for(m_per_px: float, lat: float) -> int:
    """The coarsest XYZ zoom whose tiles are at least as fine as m_per_px at `lat`."""
    z = math.ceil(math.log2(xyz_ground_m_per_px(0, lat) / m_per_px) - 1e-9)
    return min(max(z, 0), MAX_ZOOM)


@dataclass(frozen=True)
class _OutputRaster:
    """The output raster: UTM zone `epsg`, north-up, `m_per_px`; transform maps (col, row) to (E, N) metres."""

    epsg: int
    transform: Affine
    width: int
    height: int
    m_per_px: float


def _utm_grid(bbox: BBox, m_per_px: float) -> _OutputRaster:
    proj = UtmProjector.for_latlon(*bbox.centre)
    lats, lons = np.meshgrid(np.linspace(bbox.south, bbox.north, 9), np.linspace(bbox.west, bbox.east, 9))
    E, N = proj.to_utm(lats.ravel(), lons.ravel())
    e0, n1 = math.floor(np.min(E) / m_per_px) * m_per_px, math.ceil(np.max(N) / m_per_px) * m_per_px
    width = max(1, math.ceil((np.max(E) - e0) / m_per_px - 1e-9))
    height = max(1, math.ceil((n1 - np.min(N)) / m_per_px - 1e-9))
    return _OutputRaster(proj.epsg, Affine(m_per_px, 0.0, e0, 0.0, -m_per_px, n1), width, height, m_per_px)


def _windows(width: int, height: int) -> list[Window]:
    return [Window(c, r, min(WINDOW_PX, width - c), min(WINDOW_PX, height - r))
            for r in range(0, height, WINDOW_PX) for c in range(0, width, WINDOW_PX)]


# ------------------------------------------------------------------------------------------------ the work

@dataclass(frozen=True)
class MapResult:
    """A written map. path: the GeoTIFF; epsg: its UTM zone; width, height: px; m_per_px: metres per pixel;
    bounds_utm: (E_min, N_min, E_max, N_max) metres, outer pixel edges; zoom: the XYZ zoom read (WMTS: the
    zoom level asked for, else None; WMS: None); imagery_fraction: share of pixels with imagery (alpha > 0);
    cache_dir: where GDAL keeps the tiles."""

    path: Path
    epsg: int
    width: int
    height: int
    m_per_px: float
    bounds_utm: tuple[float, float, float, float]
    zoom: int | None
    imagery_fraction: float
    cache_dir: Path


def build_map(bbox: BBox, source: MapSource | str, out: str | Path, *, m_per_px: float | None = None,
              zoom: int | None = None, cache_dir: str | Path | None = None, connections: int = 2,
              user_agent: str = DEFAULT_USER_AGENT, timeout_s: float = 30.0, retries: int = 3,
              retry_delay_s: float = 1.0, progress: bool = True) -> MapResult:
    """Fetch the imagery of `bbox` from `source` through GDAL and write it as a UTM GeoTIFF at `out`.

    m_per_px: the output's resolution, metres per pixel (default: the source's own at the bbox centre); zoom:
    the XYZ zoom, or the WMTS zoom level (index of the tile matrix), to read (default for XYZ: the coarsest as
    fine as m_per_px; for WMTS: the one GDAL picks for m_per_px); a WMS needs one of the two. connections: GDAL's
    MaxConnections, parallel requests at most; timeout_s: per request; retries: further reads of a window that
    failed on a transient error, after retry_delay_s, 2 retry_delay_s, ... The map is written to `out`.part and
    renamed when complete, so an interrupted run leaves no half map; its tiles stay in the cache.

    Errors: UsageError for a bbox or option that cannot work (the estimate of the disk needed over the free
    space, a WMS without a resolution); MapSourceError for a server that cannot be reached, refuses tiles, or has
    no imagery anywhere in the bbox.
    """
    source = parse_source(source) if isinstance(source, str) else source
    out = Path(out)
    check_request(source, m_per_px, zoom, connections)
    lat, _ = bbox.centre
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    http = GdalHttp(cache, connections, user_agent, timeout_s)
    xyz_zoom: int | None = None
    if source.kind is SourceKind.XYZ:
        xyz_zoom = zoom if zoom is not None else _zoom_for(m_per_px, lat)  # type: ignore[arg-type]
        src_m_per_px: float | None = xyz_ground_m_per_px(xyz_zoom, lat)
        m_per_px = m_per_px or src_m_per_px
    elif source.kind is SourceKind.WMS:
        m_per_px = src_m_per_px = m_per_px or xyz_ground_m_per_px(zoom, lat)  # type: ignore[arg-type]
    else:
        src_m_per_px = m_per_px
    xml = service_xml(source, bbox, xyz_zoom if xyz_zoom is not None else zoom, m_per_px, http)
    cache.mkdir(parents=True, exist_ok=True)
    with rasterio.Env(GDAL_PAM_ENABLED="NO", GDAL_HTTP_USERAGENT=user_agent, GDAL_HTTP_TIMEOUT=str(int(timeout_s))):
        src = _open_source(xml, source)
        try:
            if m_per_px is None:  # a WMTS's own resolution
                x_res = src.res[0] * ground_m_per_unit(src.crs.to_string(), *bbox.centre)
                m_per_px = src_m_per_px = round(x_res, 4)
            grid = _utm_grid(bbox, m_per_px)  # type: ignore[arg-type]
            _check_disk(bbox, grid, src_m_per_px or m_per_px, out, cache)  # type: ignore[arg-type]
            log.info("map %s: %s from %s%s -> EPSG:%d, %d x %d px at %.3f m/px", out, bbox, source.name,
                     f" zoom {xyz_zoom}" if xyz_zoom is not None else "", grid.epsg, grid.width, grid.height,
                     grid.m_per_px)
            fraction = _write(src, grid, out, source, xyz_zoom if xyz_zoom is not None else zoom, http,
                              retries, retry_delay_s, progress)
        finally:
            src.close()
    b = grid.transform
    bounds = (b.c, b.f - grid.height * grid.m_per_px, b.c + grid.width * grid.m_per_px, b.f)
    return MapResult(out, grid.epsg, grid.width, grid.height, grid.m_per_px, bounds,
                     xyz_zoom if xyz_zoom is not None else zoom if source.kind is SourceKind.WMTS else None,
                     fraction, cache)


def check_request(source: MapSource, m_per_px: float | None, zoom: int | None, connections: int) -> None:
    """UsageError (naming the option) for a resolution or a concurrency `build_map` cannot work with."""
    if m_per_px is None and zoom is None and source.kind is not SourceKind.WMTS:
        raise UsageError(f"give --m-per-px M or --zoom Z (the map's resolution: an {source.kind.value.upper()} "
                         "source has none of its own)")
    if m_per_px is not None and not (math.isfinite(m_per_px) and 0.01 <= m_per_px <= 1000.0):
        raise UsageError(f"--m-per-px {m_per_px:g}: must lie within [0.01, 1000] metres per pixel")
    if zoom is not None and not 0 <= zoom <= MAX_ZOOM:
        raise UsageError(f"--zoom {zoom}: must lie within [0, {MAX_ZOOM}]")
    if not 1 <= connections <= 16:
        raise UsageError(f"--connections {connections}: must lie within [1, 16]")


def _open_source(xml: str, source: MapSource) -> rasterio.DatasetReader:
    """Open GDAL's description of the service (a WMTS's capabilities are read here); MapSourceError if GDAL
    cannot."""
    try:
        return rasterio.open(xml)
    except RasterioIOError as exc:
        failure = read_failure(exc)
        if source.kind is SourceKind.WMTS:
            raise MapSourceError(f"{source.url}: cannot read the WMTS capabilities ({failure.error})",
                                 url=source.url, status=failure.status) from None
        raise MapSourceError(f"{source.name}: GDAL cannot open the service ({failure.error})", url=source.url,
                             status=failure.status) from None


def _free_bytes(folder: Path) -> tuple[int, int]:
    """(free bytes, device id) of the file system holding `folder` (or its nearest existing parent)."""
    existing = next(p for p in (folder, *folder.parents) if p.exists())
    return shutil.disk_usage(existing).free, os.stat(existing).st_dev


def _check_disk(bbox: BBox, grid: _OutputRaster, src_m_per_px: float, out: Path, cache: Path) -> None:
    """UsageError when the GeoTIFF and the tiles it needs would not fit on the disk(s) they go to."""
    px = grid.width * grid.height
    out_bytes = px * OUTPUT_BYTES_PER_PX
    cache_bytes = px * (grid.m_per_px / src_m_per_px) ** 2 * CACHE_BYTES_PER_PX
    out_dir = out.parent if str(out.parent) else Path(".")
    (out_free, out_dev), (cache_free, cache_dev) = _free_bytes(out_dir.resolve()), _free_bytes(cache.resolve())
    needs = [(out_dir, out_bytes + (cache_bytes if out_dev == cache_dev else 0.0), out_free)]
    if out_dev != cache_dev:
        needs.append((cache, cache_bytes, cache_free))
    for folder, need, free in needs:
        if need > free:
            raise UsageError(
                f"--bbox {bbox}: the map needs about {need / 1e9:.2f} GB in {folder} ({grid.width} x {grid.height} "
                f"px at {grid.m_per_px:g} m/px: up to {out_bytes / 1e9:.2f} GB of GeoTIFF, {cache_bytes / 1e9:.2f} "
                f"GB of cached tiles in {cache}) but {free / 1e9:.2f} GB are free: a smaller bbox, a coarser "
                "--m-per-px or another --out / --cache")


def _write(src: rasterio.DatasetReader, grid: _OutputRaster, out: Path, source: MapSource, zoom: int | None,
           http: GdalHttp, retries: int, retry_delay_s: float, progress: bool) -> float:
    """Warp the service into the grid, window by window, into out.part; rename it to out. Returns the share of
    pixels with imagery; MapSourceError when there is none."""
    profile = dict(driver="GTiff", width=grid.width, height=grid.height, count=4, dtype="uint8",
                   crs=f"EPSG:{grid.epsg}", transform=grid.transform, photometric="RGB", alpha="YES",
                   interleave="pixel", tiled=True, blockxsize=BLOCK_PX, blockysize=BLOCK_PX, compress="deflate",
                   predictor=2, bigtiff="IF_SAFER")
    part = out.with_name(out.name + ".part")
    out.parent.mkdir(parents=True, exist_ok=True)
    imagery = 0
    windows = _windows(grid.width, grid.height)
    try:
        with WarpedVRT(src, crs=f"EPSG:{grid.epsg}", transform=grid.transform, width=grid.width,
                       height=grid.height, resampling=Resampling.bilinear) as vrt, \
                rasterio.open(part, "w", **profile) as dst:
            if vrt.count != 4:
                raise MapSourceError(f"{source.name}: GDAL reads {vrt.count} bands, RGBA (4) expected",
                                     url=source.url, status=None)
            for window in progress_bar(windows, total=len(windows), desc=f"map {out.name}", enabled=progress):
                data = _read(vrt, window, source, zoom, http, retries, retry_delay_s)
                dst.write(data, window=window)
                imagery += int(np.count_nonzero(data[3]))
        if imagery == 0:
            example = source.name
            if source.kind is SourceKind.XYZ and zoom is not None:
                example = source.tile_url(zoom, *xyz_tile(*_centre_latlon(grid), zoom))
            raise MapSourceError(f"{example}: no imagery anywhere in the bbox (every tile was missing: HTTP 404 or "
                                 "204, or empty): check the URL, the layer and the zoom", url=example, status=404)
        os.replace(part, out)
    finally:
        part.unlink(missing_ok=True)
    fraction = imagery / (grid.width * grid.height)
    if fraction < 0.999:
        log.warning("%s: %.1f %% of the map has no imagery (alpha 0): the service had no tiles there (HTTP 404)",
                    out, 100.0 * (1.0 - fraction))
    return fraction


def _centre_latlon(grid: _OutputRaster) -> tuple[float, float]:
    tr = grid.transform
    e, n = tr.c + tr.a * grid.width / 2.0, tr.f + tr.e * grid.height / 2.0
    lat, lon = UtmProjector(grid.epsg).to_latlon(e, n)
    return float(lat), float(lon)


def _read(vrt: WarpedVRT, window: Window, source: MapSource, zoom: int | None, http: GdalHttp, retries: int,
          retry_delay_s: float) -> np.ndarray:
    """One window (4, h, w) uint8, read again after a transient failure (GDAL's WMS driver does not retry)."""
    for attempt in _attempts(retries):
        try:
            return vrt.read(window=window)
        except RasterioIOError as exc:
            failure = read_failure(exc)
            if not failure.transient or attempt == retries:
                raise source_error(failure, source, zoom, http, attempt + 1) from None
            delay = retry_delay_s * 2 ** attempt
            log.warning("%s: %s (HTTP %s); reading again in %.1f s (%d of %d)", failure_place(failure, source, zoom),
                        failure.error, failure.status, delay, attempt + 1, retries)
            time.sleep(delay)
    raise AssertionError("unreachable")  # pragma: no cover


def _attempts(retries: int) -> Iterator[int]:
    yield from range(max(0, retries) + 1)
