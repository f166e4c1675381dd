"""What GDAL's WMS driver is told about a map service, and what its errors say (`taco-mav map`).

A --source is parsed into a `MapSource` (an XYZ tile template, a WMTS, a WMS), and written as the service
description GDAL reads: a GDAL_WMS XML (TMS mini-driver) for an XYZ template, a GDAL_WMTS XML for a WMTS (GDAL
reads its GetCapabilities and builds the GDAL_WMS of each level), a GDAL_WMS XML (WMS mini-driver) for a WMS.
Each carries the same network settings (`GdalHttp`): MaxConnections, Timeout, UserAgent, the disk cache
(<Cache><Path>, one sub-folder per service URL) and HTTP 404/204 read as "no tile here" (zeros, alpha 0). No
tile is ever fetched here: `taco_mav.datasets.map_tiles` opens the XML with rasterio and GDAL fetches.

GDAL reports a failed tile as an exception chain whose text carries the HTTP status and the block, not the URL;
`read_failure` reads it, `source_error` turns it into a `MapSourceError` naming the tile's URL (XYZ: the block is the
tile at the zoom, no overviews being declared) or the service and its layer (WMTS, WMS).

Frames and units: bbox in WGS84 degrees; XYZ tiles in Web Mercator (EPSG:3857), 256 x 256 px, x east and y south
from the world's north-west corner ({-y}: y north from the south-west, TMS); zoom z has a ground resolution of
156543.03 cos(lat) / 2^z m/px.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit
from xml.sax.saxutils import escape

import numpy as np
from pyproj import Transformer

from taco_mav import __version__
from taco_mav.errors import MapSourceError, UsageError
from taco_mav.geo import UtmProjector

__all__ = ["BBox", "DEFAULT_USER_AGENT", "Failure", "GdalHttp", "MapSource", "SourceKind", "default_cache_dir",
           "ground_m_per_unit", "parse_source", "read_failure", "service_xml", "source_error", "xyz_ground_m_per_px",
           "xyz_tile"]

HALF_WORLD_M = 20037508.342789244  # half the Web Mercator world's width, metres
TILE_PX = 256  # XYZ tile side, px
MAX_ZOOM = 24
MAX_SPAN_DEG = 6.0  # a bbox wider or taller than one UTM zone (6 deg) is refused: a rover's map is a few km
WMS_BLOCK_PX = 512  # one WMS GetMap request, px
CACHE_EXPIRES_S = 365 * 24 * 3600  # a cached tile is used for a year (GDAL's default: 7 days)
DEFAULT_USER_AGENT = f"taco-mav/{__version__} (map builder; GDAL WMS driver)"
_TRANSIENT_STATUS = frozenset({0, 408, 429, 500, 502, 503, 504})


# ------------------------------------------------------------------------------------------------ the request

@dataclass(frozen=True)
class BBox:
    """An area in WGS84 degrees: south < north, west < east (not across the antimeridian)."""

    south: float
    west: float
    north: float
    east: float

    @classmethod
    def parse(cls, text: str) -> "BBox":
        """`LAT0,LON0,LAT1,LON1` (any two opposite corners, degrees) -> a checked BBox; UsageError naming --bbox."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 4:
            raise UsageError(f"--bbox {text}: expected LAT0,LON0,LAT1,LON1 in degrees")
        return cls.from_corners(*values)

    @classmethod
    def from_corners(cls, lat0: float, lon0: float, lat1: float, lon1: float) -> "BBox":
        """Two opposite corners, degrees -> a checked BBox (UsageError naming --bbox when it is not a usable area)."""
        text = f"{lat0:g},{lon0:g},{lat1:g},{lon1:g}"
        if not all(math.isfinite(v) for v in (lat0, lon0, lat1, lon1)):
            raise UsageError(f"--bbox {text}: not finite")
        if not (-80.0 <= min(lat0, lat1) and max(lat0, lat1) <= 84.0 and -180.0 <= min(lon0, lon1)
                and max(lon0, lon1) <= 180.0):
            raise UsageError(f"--bbox {text}: latitudes must lie within [-80, 84] (UTM) and longitudes within "
                             "[-180, 180] degrees")
        if lat0 == lat1 or lon0 == lon1:
            raise UsageError(f"--bbox {text}: an empty area (give two opposite corners)")
        if abs(lat1 - lat0) > MAX_SPAN_DEG or abs(lon1 - lon0) > MAX_SPAN_DEG:
            raise UsageError(f"--bbox {text}: spans more than {MAX_SPAN_DEG:g} degrees (a UTM zone's width); a "
                             "rover's map covers a few km (an area across the antimeridian: one map each side)")
        return cls(min(lat0, lat1), min(lon0, lon1), max(lat0, lat1), max(lon0, lon1))

    @property
    def centre(self) -> tuple[float, float]:
        """(lat, lon) degrees of the middle of the box."""
        return 0.5 * (self.south + self.north), 0.5 * (self.west + self.east)

    def __str__(self) -> str:
        return f"{self.south:g},{self.west:g},{self.north:g},{self.east:g}"


class SourceKind(str, Enum):
    """How the imagery is served."""

    XYZ = "xyz"  # a tile URL template with {z}, {x}, {y} (or {-y})
    WMTS = "wmts"  # an OGC WMTS: its GetCapabilities URL, a layer
    WMS = "wms"  # an OGC WMS: its URL, a layer (GetMap at any resolution)


@dataclass(frozen=True)
class MapSource:
    """A parsed --source. url: XYZ: the template (GDAL's ${z}/${x}/${y}); WMTS: the GetCapabilities URL; WMS: the
    service URL with its own parameters (an API key, MAP=...) but none of GetMap's. params: WMTS: layer,
    tilematrixset, style (lower case); WMS: layers, styles, format, crs, version, transparent. tms_y: XYZ whose y
    counts from the south ({-y}). text: the --source as given."""

    kind: SourceKind
    url: str
    params: tuple[tuple[str, str], ...]
    text: str
    tms_y: bool = False

    def param(self, name: str, default: str = "") -> str:
        return dict(self.params).get(name, default)

    def tile_url(self, zoom: int, x: int, y: int) -> str:
        """An XYZ tile's URL (x, y: the tile's column and row counted from the north-west)."""
        y_url = (2 ** zoom - 1 - y) if self.tms_y else y
        return self.url.replace("${z}", str(zoom)).replace("${x}", str(x)).replace("${y}", str(y_url))

    @property
    def name(self) -> str:
        """What an error names: the template, or the service and its layer."""
        if self.kind is SourceKind.XYZ:
            return self.text
        layer = self.param("layer") or self.param("layers")
        return f"{self.kind.value.upper()} {self.url}" + (f" layer {layer}" if layer else "")


_WMS_GETMAP_KEYS = frozenset({"service", "request", "bbox", "width", "height", "layers", "styles", "format", "crs",
                              "srs", "version", "transparent"})


def parse_source(text: str) -> MapSource:
    """--source -> MapSource. Forms: `https://host/{z}/{x}/{y}.png` (XYZ; {-y} for TMS rows, GDAL's ${z} too),
    `WMTS:https://host/WMTSCapabilities.xml[,layer=NAME][,tilematrixset=TMS][,style=S]` (GDAL's syntax),
    `WMS:https://host/wms?LAYERS=NAME[&STYLES=..][&FORMAT=image/jpeg][&CRS=EPSG:3857][&VERSION=1.3.0]`.
    UsageError naming --source for anything else."""
    raw = text.strip()
    if raw[:5].upper() == "WMTS:":
        url, *rest = raw[5:].split(",")
        params = []
        for item in rest:
            key, sep, value = item.partition("=")
            if not sep or key.strip().lower() not in ("layer", "tilematrixset", "style", "tilematrix"):
                raise UsageError(f"--source {text}: {item!r}: expected layer=, tilematrixset=, style= or "
                                 "tilematrix=")
            params.append((key.strip().lower(), value.strip()))
        _check_url(url, text)
        return MapSource(SourceKind.WMTS, url, tuple(params), text)
    if raw[:4].upper() == "WMS:":
        url = raw[4:]
        _check_url(url, text)
        parts = urlsplit(url)
        query = parse_qsl(parts.query, keep_blank_values=True)
        given = {k.lower(): v for k, v in query}
        if not given.get("layers"):
            raise UsageError(f"--source {text}: a WMS source needs LAYERS=NAME in its URL (its GetCapabilities "
                             "lists them)")
        version = given.get("version", "1.1.1")
        params = (("layers", given["layers"]), ("styles", given.get("styles", "")),
                  ("format", given.get("format", "image/png")), ("version", version),
                  ("crs", given.get("crs") or given.get("srs") or "EPSG:3857"),
                  ("transparent", given.get("transparent", "TRUE")))
        own = [(k, v) for k, v in query if k.lower() not in _WMS_GETMAP_KEYS]
        base = urlunsplit((parts.scheme, parts.netloc, parts.path, urlencode(own), ""))
        return MapSource(SourceKind.WMS, base, params, text)
    template = re.sub(r"\$\{(-?[xyz])\}", r"{\1}", raw)
    if all(f"{{{k}}}" in template for k in "zx") and ("{y}" in template) != ("{-y}" in template):
        _check_url(template, text)
        tms = "{-y}" in template
        gdal = template.replace("{z}", "${z}").replace("{x}", "${x}").replace("{-y}" if tms else "{y}", "${y}")
        return MapSource(SourceKind.XYZ, gdal, (), text, tms_y=tms)
    raise UsageError(f"--source {text}: expected an XYZ tile URL with {{z}}, {{x}} and {{y}} (or {{-y}}), "
                     "WMTS:CAPABILITIES_URL[,layer=NAME] or WMS:URL?LAYERS=NAME")


def _check_url(url: str, text: str) -> None:
    if urlsplit(url).scheme.lower() not in ("http", "https", "file"):
        raise UsageError(f"--source {text}: {url!r} is not an http(s):// or file:// URL")


def default_cache_dir() -> Path:
    """Where tiles are cached unless told: $XDG_CACHE_HOME/taco_mav/tiles (~/.cache/taco_mav/tiles). GDAL keeps
    one sub-folder per service URL."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "taco_mav" / "tiles"


# ------------------------------------------------------------------------------------------------ Web Mercator

def xyz_ground_m_per_px(zoom: int, lat: float) -> float:
    """Ground resolution of XYZ zoom `zoom` at latitude `lat` degrees, metres per pixel."""
    return 2.0 * HALF_WORLD_M / TILE_PX / 2 ** zoom * math.cos(math.radians(lat))


def xyz_tile(lat: float, lon: float, zoom: int) -> tuple[int, int]:
    """The XYZ tile (x east, y south, from the north-west) holding a WGS84 point, degrees."""
    n = 2 ** zoom
    x = (lon + 180.0) / 360.0 * n
    y = (1.0 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2.0 * n
    return min(int(x), n - 1), min(max(int(y), 0), n - 1)


def ground_m_per_unit(crs: str, lat: float, lon: float) -> float:
    """Ground metres per unit of `crs` along x at a WGS84 point (degrees): 1/cos(lat) in Web Mercator."""
    to_crs = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    utm = UtmProjector.for_latlon(lat, lon)
    x, y = to_crs.transform(lon, lat)
    step = 1e-6 * max(abs(x), abs(y), 1.0)
    la, lo = Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform([x, x + step], [y, y])[::-1]
    e, n = utm.to_utm(np.asarray(la), np.asarray(lo))
    return float(math.hypot(e[1] - e[0], n[1] - n[0]) / step)


# ------------------------------------------------------------------------------------------------ GDAL's XML

@dataclass(frozen=True)
class GdalHttp:
    """What GDAL's WMS driver is told about the network and the cache."""

    cache_dir: Path
    connections: int
    user_agent: str
    timeout_s: float

    def xml(self) -> str:
        return (f"<MaxConnections>{self.connections}</MaxConnections>"
                f"<Timeout>{max(1, round(self.timeout_s))}</Timeout>"
                f"<UserAgent>{escape(self.user_agent)}</UserAgent>"
                "<ZeroBlockHttpCodes>204,404</ZeroBlockHttpCodes>"
                f"<Cache><Path>{escape(str(self.cache_dir))}</Path><Expires>{CACHE_EXPIRES_S}</Expires>"
                "<CleanTimeout>0</CleanTimeout></Cache>")


def _xyz_xml(source: MapSource, zoom: int, http: GdalHttp) -> str:
    """GDAL_WMS (TMS mini-driver) over the whole Web Mercator world at `zoom`: block (x, y) is tile (x, y);
    no overviews, so that every block read is a tile at this zoom."""
    h = HALF_WORLD_M
    return (f"<GDAL_WMS><Service name=\"TMS\"><ServerUrl>{escape(source.url)}</ServerUrl></Service>"
            f"<DataWindow><UpperLeftX>{-h!r}</UpperLeftX><UpperLeftY>{h!r}</UpperLeftY>"
            f"<LowerRightX>{h!r}</LowerRightX><LowerRightY>{-h!r}</LowerRightY><TileLevel>{zoom}</TileLevel>"
            f"<TileCountX>1</TileCountX><TileCountY>1</TileCountY>"
            f"<YOrigin>{'bottom' if source.tms_y else 'top'}</YOrigin></DataWindow>"
            f"<Projection>EPSG:3857</Projection><BlockSizeX>{TILE_PX}</BlockSizeX><BlockSizeY>{TILE_PX}</BlockSizeY>"
            f"<BandsCount>4</BandsCount><OverviewCount>0</OverviewCount>{http.xml()}</GDAL_WMS>")


def _wmts_xml(source: MapSource, zoom: int | None, http: GdalHttp) -> str:
    """GDAL_WMTS: GDAL reads the capabilities, picks the tile matrix set and builds the GDAL_WMS of each level."""
    names = {"layer": "Layer", "tilematrixset": "TileMatrixSet", "style": "Style", "tilematrix": "TileMatrix"}
    parts = "".join(f"<{names[k]}>{escape(v)}</{names[k]}>" for k, v in source.params)
    if zoom is not None:
        parts += f"<ZoomLevel>{zoom}</ZoomLevel>"
    return (f"<GDAL_WMTS><GetCapabilitiesUrl>{escape(source.url)}</GetCapabilitiesUrl>{parts}"
            f"<BandsCount>4</BandsCount>{http.xml()}</GDAL_WMTS>")


def _wms_xml(source: MapSource, bbox: BBox, m_per_px: float, http: GdalHttp) -> str:
    """GDAL_WMS (WMS mini-driver): GetMap blocks of WMS_BLOCK_PX in the source's CRS, at the ground resolution
    m_per_px at the bbox centre (or up to 4 % finer: the CRS resolution is one of a ladder), over the bbox with a
    margin; the block grid is snapped to multiples of its own size, so that another bbox nearby at the same
    resolution asks (and finds in the cache) the same requests."""
    crs = source.param("crs")
    lat, lon = bbox.centre
    res = m_per_px / ground_m_per_unit(crs, lat, lon)  # CRS units per pixel, on a ladder of 1/16 octave (finer):
    res = 2.0 ** (math.floor(math.log2(res) * 16 + 1e-9) / 16)  # bboxes near each other ask the same GetMaps
    to_crs = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    lats, lons = np.meshgrid(np.linspace(bbox.south, bbox.north, 9), np.linspace(bbox.west, bbox.east, 9))
    x, y = (np.asarray(v) for v in to_crs.transform(lons.ravel(), lats.ravel()))
    step = res * WMS_BLOCK_PX
    x0, x1 = math.floor((x.min() - 4 * res) / step) * step, math.ceil((x.max() + 4 * res) / step) * step
    y0, y1 = math.floor((y.min() - 4 * res) / step) * step, math.ceil((y.max() + 4 * res) / step) * step
    size_x, size_y = round((x1 - x0) / res), round((y1 - y0) / res)
    version = source.param("version")
    crs_tag = "CRS" if version.startswith("1.3") else "SRS"
    service = (f"<Service name=\"WMS\"><Version>{escape(version)}</Version>"
               f"<ServerUrl>{escape(source.url)}</ServerUrl><{crs_tag}>{escape(crs)}</{crs_tag}>"
               f"<ImageFormat>{escape(source.param('format'))}</ImageFormat>"
               f"<Transparent>{escape(source.param('transparent'))}</Transparent>"
               f"<Layers>{escape(source.param('layers'))}</Layers><Styles>{escape(source.param('styles'))}</Styles>"
               "</Service>")
    return (f"<GDAL_WMS>{service}<DataWindow><UpperLeftX>{x0!r}</UpperLeftX><UpperLeftY>{y1!r}</UpperLeftY>"
            f"<LowerRightX>{x1!r}</LowerRightX><LowerRightY>{y0!r}</LowerRightY>"
            f"<SizeX>{size_x}</SizeX><SizeY>{size_y}</SizeY></DataWindow>"
            f"<Projection>{escape(crs)}</Projection><BlockSizeX>{WMS_BLOCK_PX}</BlockSizeX>"
            f"<BlockSizeY>{WMS_BLOCK_PX}</BlockSizeY><BandsCount>4</BandsCount><OverviewCount>0</OverviewCount>"
            f"{http.xml()}</GDAL_WMS>")


def service_xml(source: MapSource, bbox: BBox, zoom: int | None, m_per_px: float | None, http: GdalHttp) -> str:
    """GDAL's description of `source`: XYZ at `zoom`; WMTS at `zoom` (a tile matrix index) or all its levels;
    WMS over `bbox` at `m_per_px` (ground metres per pixel at the bbox centre)."""
    if source.kind is SourceKind.WMTS:
        return _wmts_xml(source, zoom, http)
    if source.kind is SourceKind.XYZ and zoom is not None:
        return _xyz_xml(source, zoom, http)
    if source.kind is SourceKind.WMS and m_per_px is not None:
        return _wms_xml(source, bbox, m_per_px, http)
    raise UsageError(f"--source {source.text}: give --zoom Z or --m-per-px M")


# ------------------------------------------------------------------------------------------------ GDAL's errors

@dataclass(frozen=True)
class Failure:
    """One failed read as GDAL's WMS driver reports it: HTTP status (0: no answer), curl's or the server's
    text, the block (tile column, row at the read level) where known."""

    status: int | None
    error: str
    block: tuple[int, int] | None
    text: str

    @property
    def transient(self) -> bool:
        """Worth another try: no answer (a dropped connection, a timeout), HTTP 408, 429 or 5xx."""
        return self.status in _TRANSIENT_STATUS


def read_failure(exc: BaseException) -> Failure:
    """Read the cause chain rasterio attaches (CPLE_AppDefinedError ... from GDALWMS)."""
    texts = []
    seen: BaseException | None = exc
    while seen is not None and len(texts) < 20:
        texts.append(str(seen))
        seen = seen.__cause__ or seen.__context__
    text = "\n".join(texts)
    status = re.search(r"HTTP status code: (-?\d+)", text)
    error = re.search(r"HTTP status code: -?\d+, error: (.*?)\.?\n", text + "\n")
    block = re.search(r"Unable to download block (\d+), (\d+)", text)
    if error is None or error.group(1) == "(null)":
        error = re.search(r"(GDALWMS: [^\n]*exception[^\n]*|ServiceException[^\n]*|HTTP error code ?: ?\d+[^\n]*|"
                          r"Could(?: not|n't) [^\n]*|Failed to connect[^\n]*)", text, re.IGNORECASE)
    return Failure(status=int(status.group(1)) if status else None,
                   error=error.group(1).strip() if error else texts[-1].strip(),
                   block=(int(block.group(1)), int(block.group(2))) if block else None, text=text)


_UNREACHABLE = re.compile(r"connect|resolve|refused|unreachable|no route", re.IGNORECASE)


def failure_place(failure: Failure, source: MapSource, zoom: int | None) -> str:
    """The tile's URL (XYZ), else the service, its layer and the block."""
    if source.kind is SourceKind.XYZ and failure.block is not None and zoom is not None:
        return source.tile_url(zoom, *failure.block)
    if failure.block is not None:
        return f"{source.name} (block {failure.block[0]}, {failure.block[1]})"
    return source.name


def source_error(failure: Failure, source: MapSource, zoom: int | None, http: GdalHttp,
                 tries: int) -> MapSourceError:
    """The error a user reads: what failed, where (the tile URL for XYZ), and what to do about it."""
    where = failure_place(failure, source, zoom)
    status, error = failure.status, failure.error
    resume = f"; the tiles fetched so far are kept in {http.cache_dir}, a re-run resumes"
    if status == 0 and _UNREACHABLE.search(error):
        return MapSourceError(f"{where}: cannot reach the server ({error}): check the URL and the network{resume}",
                              url=where, status=0)
    if status == 0:
        return MapSourceError(f"{where}: no answer after {tries} tries ({error}; --timeout {http.timeout_s:g} s): "
                              f"the server is slow or drops requests; try fewer --connections{resume}",
                              url=where, status=0)
    if status in (401, 403):
        return MapSourceError(f"{where}: the server refused the tile (HTTP {status}): it may want an API key in the "
                              f"URL, a login, or another User-Agent than {http.user_agent!r} (--user-agent); read "
                              f"its terms of use{resume}", url=where, status=status)
    if status is not None:
        return MapSourceError(f"{where}: HTTP {status} after {tries} tries ({error}){resume}", url=where,
                              status=status)
    return MapSourceError(f"{where}: GDAL could not read it ({error})", url=where, status=None)
