"""taco_mav/datasets/map_tiles.py (`taco-mav map`): a tile server on 127.0.0.1 serves XYZ tiles, a WMTS and a WMS
cut from a seeded Web Mercator mosaic; the UTM GeoTIFF written through GDAL's WMS driver must match the mosaic
(geolocation within a pixel, high correlation), be tiled, compressed and transparent where the server had no tile,
come from the cache on a second run, survive dropped and late tiles, and fail with a named error when the server
is unreachable, refuses tiles, has none, or the disk is too small. A local tile folder (a tile cache) read through
a file:// template gives the same map."""

from __future__ import annotations

import http.server
import math
import re
import socket
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator
from urllib.parse import parse_qsl, urlsplit

import cv2
import numpy as np
import pytest
import rasterio
from pyproj import Transformer
from rasterio.enums import ColorInterp, Compression

from taco_mav import cli
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.datasets import map_tiles
from taco_mav.datasets.map_sources import HALF_WORLD_M, BBox, xyz_ground_m_per_px, xyz_tile
from taco_mav.datasets.map_tiles import build_map
from taco_mav.errors import MapSourceError, UsageError
from taco_mav.geo import UtmProjector

LAT, LON, ZOOM = 49.0105, 8.4035, 18  # Karlsruhe, UTM 32N; zoom 18: 0.39 m/px there
HALF_TILES = 2  # the mosaic: 5 x 5 tiles around the centre's tile
TILE_M = 2 * HALF_WORLD_M / 2 ** ZOOM
BBOX = BBox.from_corners(LAT - 0.0011, LON - 0.0016, LAT + 0.0011, LON + 0.0016)  # ~240 x 230 m
CX, CY = xyz_tile(LAT, LON, ZOOM)
HOLE = (CX + 1, CY)  # the tile the server has not got (HTTP 404), inside the bbox
SLOW = (CX, CY + 1)  # the tile the flaky server answers late the first time


@dataclass
class Mosaic:
    """RGB (H, W, 3) uint8 in Web Mercator at ZOOM: pixel (0, 0)'s outer corner is tile (x0, y0)'s."""

    image: np.ndarray
    x0: int
    y0: int

    @property
    def origin_m(self) -> tuple[float, float]:
        """(X, Y) EPSG:3857 metres of the north-west outer corner."""
        return -HALF_WORLD_M + self.x0 * TILE_M, HALF_WORLD_M - self.y0 * TILE_M

    def tile(self, x: int, y: int) -> np.ndarray | None:
        c, r = (x - self.x0) * 256, (y - self.y0) * 256
        if not (0 <= c < self.image.shape[1] and 0 <= r < self.image.shape[0]):
            return None
        return self.image[r:r + 256, c:c + 256]

    def render(self, x0: float, y0: float, x1: float, y1: float, width: int, height: int) -> np.ndarray:
        """RGBA (height, width, 4): the EPSG:3857 box (x0, y0, x1, y1) metres, bilinear, alpha 0 off the mosaic."""
        res = TILE_M / 256
        mx, my = self.origin_m
        sx, sy = (x1 - x0) / width, (y1 - y0) / height
        # output pixel (i, j) centre -> mosaic pixel coordinates (pixel centres at integers)
        M = np.array([[sx / res, 0.0, (x0 + 0.5 * sx - mx) / res - 0.5],
                      [0.0, sy / res, (my - y1 + 0.5 * sy) / res - 0.5]])
        rgba = np.dstack([self.image, np.full(self.image.shape[:2], 255, np.uint8)])
        return cv2.warpAffine(rgba, M, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))


def make_mosaic(seed: int = 7) -> Mosaic:
    """A seeded texture of blobs at 24 and 6 px, 5 x 5 tiles of 256 px."""
    rng = np.random.default_rng(seed)
    size = (2 * HALF_TILES + 1) * 256
    img = np.zeros((size, size, 3), np.float32)
    for cell, weight in ((24, 1.0), (6, 0.5)):
        noise = rng.standard_normal((size // cell + 2, size // cell + 2, 3)).astype(np.float32)
        img += weight * cv2.resize(noise, (size + 2 * cell, size + 2 * cell), interpolation=cv2.INTER_CUBIC)[
            cell:cell + size, cell:cell + size]
    img = (img - img.mean()) / img.std()
    return Mosaic(np.clip(128 + 45 * img, 0, 255).astype(np.uint8), CX - HALF_TILES, CY - HALF_TILES)


def _png(image: np.ndarray) -> bytes:
    code = cv2.COLOR_RGBA2BGRA if image.shape[2] == 4 else cv2.COLOR_RGB2BGR
    return cv2.imencode(".png", cv2.cvtColor(image, code))[1].tobytes()


def wmts_capabilities(base: str) -> str:
    """A minimal WMTS 1.0.0 GetCapabilities: layer `test` on GoogleMapsCompatible 0..ZOOM, RESTful tiles."""
    matrices = "".join(
        f"<TileMatrix><ows:Identifier>{z}</ows:Identifier><ScaleDenominator>{559082264.0287178 / 2 ** z!r}"
        f"</ScaleDenominator><TopLeftCorner>-20037508.3427892 20037508.3427892</TopLeftCorner><TileWidth>256"
        f"</TileWidth><TileHeight>256</TileHeight><MatrixWidth>{2 ** z}</MatrixWidth><MatrixHeight>{2 ** z}"
        f"</MatrixHeight></TileMatrix>" for z in range(ZOOM + 1))
    return ('<?xml version="1.0" encoding="UTF-8"?><Capabilities xmlns="http://www.opengis.net/wmts/1.0" '
            'xmlns:ows="http://www.opengis.net/ows/1.1" version="1.0.0"><Contents><Layer>'
            '<ows:Identifier>test</ows:Identifier><ows:WGS84BoundingBox><ows:LowerCorner>-180 -85</ows:LowerCorner>'
            '<ows:UpperCorner>180 85</ows:UpperCorner></ows:WGS84BoundingBox><Style isDefault="true">'
            '<ows:Identifier>default</ows:Identifier></Style><Format>image/png</Format><TileMatrixSetLink>'
            '<TileMatrixSet>GoogleMapsCompatible</TileMatrixSet></TileMatrixSetLink><ResourceURL format="image/png" '
            f'resourceType="tile" template="{base}/ok/{{TileMatrix}}/{{TileCol}}/{{TileRow}}.png"/></Layer>'
            '<TileMatrixSet><ows:Identifier>GoogleMapsCompatible</ows:Identifier>'
            f'<ows:SupportedCRS>urn:ogc:def:crs:EPSG::3857</ows:SupportedCRS>{matrices}</TileMatrixSet>'
            '</Contents></Capabilities>')


@dataclass
class TileServer:
    """Modes by the first path part: ok (HOLE is 404), forbidden (403), gone (404), flaky (drops every tile's
    first request, answers SLOW's first 2 s late), wmts (capabilities), wms (GetMap)."""

    mosaic: Mosaic
    base: str = ""
    requests: dict[str, int] = field(default_factory=dict)
    statuses: dict[str, int] = field(default_factory=dict)
    user_agents: set[str] = field(default_factory=set)
    lock: threading.Lock = field(default_factory=threading.Lock)


def _handler(server: TileServer) -> type[http.server.BaseHTTPRequestHandler]:
    class Handler(http.server.BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args: object) -> None:
            pass

        def _send(self, status: int, body: bytes = b"", kind: str = "image/png") -> None:
            with server.lock:
                server.statuses[self.path] = status
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            with server.lock:
                n = server.requests[self.path] = server.requests.get(self.path, 0) + 1
                server.user_agents.add(self.headers.get("User-Agent", ""))
            url = urlsplit(self.path)
            mode = url.path.strip("/").split("/")[0]
            if mode == "wmts":
                return self._send(200, wmts_capabilities(server.base).encode(), "application/xml")
            if mode == "wms":
                q = {k.upper(): v for k, v in parse_qsl(url.query)}
                x0, y0, x1, y1 = (float(v) for v in q["BBOX"].split(","))
                img = server.mosaic.render(x0, y0, x1, y1, int(q["WIDTH"]), int(q["HEIGHT"]))
                return self._send(200, _png(img))
            m = re.fullmatch(r"/\w+/(\d+)/(\d+)/(\d+)\.png", url.path)
            if m is None:
                return self._send(400)
            z, x, y = (int(v) for v in m.groups())
            if mode == "forbidden":
                return self._send(403)
            if mode == "flaky" and n == 1:
                if (x, y) == SLOW:
                    threading.Event().wait(2.0)
                else:
                    self.close_connection = True
                    self.connection.shutdown(socket.SHUT_RDWR)
                    return None
            tile = server.mosaic.tile(x, y) if z == ZOOM else None
            if mode == "gone" or tile is None or (mode == "ok" and (x, y) == HOLE):
                return self._send(404, b"no such tile", "text/plain")
            return self._send(200, _png(tile))

    return Handler


@pytest.fixture(scope="module")
def server() -> Iterator[TileServer]:
    ts = TileServer(make_mosaic())
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _handler(ts))
    httpd.daemon_threads = True
    ts.base = f"http://127.0.0.1:{httpd.server_address[1]}"
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield ts
    httpd.shutdown()
    httpd.server_close()


def expected(mosaic: Mosaic, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The mosaic resampled onto the GeoTIFF's grid (RGB float, H x W x 3) and where it exists (bool)."""
    with rasterio.open(path) as ds:
        tr, h, w, epsg = ds.transform, ds.height, ds.width, ds.crs.to_epsg()
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    E, N = tr.c + cols * tr.a, tr.f + rows * tr.e
    lat, lon = UtmProjector(epsg).to_latlon(E, N)
    X, Y = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(lon, lat)
    res = TILE_M / 256
    mx, my = mosaic.origin_m
    u, v = ((X - mx) / res - 0.5).astype(np.float32), ((my - Y) / res - 0.5).astype(np.float32)
    img = cv2.remap(mosaic.image, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    inside = (u >= 0) & (v >= 0) & (u <= mosaic.image.shape[1] - 1) & (v <= mosaic.image.shape[0] - 1)
    return img.astype(np.float32), inside


def utm_pixel(path: Path, lat: float, lon: float) -> tuple[int, int]:
    """(row, col) of the GeoTIFF pixel holding a WGS84 point."""
    with rasterio.open(path) as ds:
        e, n = UtmProjector(ds.crs.to_epsg()).to_utm(lat, lon)
        return ds.index(e, n)


def tile_centre(x: int, y: int) -> tuple[float, float]:
    """(lat, lon) of an XYZ tile's centre at ZOOM."""
    n = 2 ** ZOOM
    lon = (x + 0.5) / n * 360.0 - 180.0
    lat = math.degrees(math.atan(math.sinh(math.pi * (1 - 2 * (y + 0.5) / n))))
    return lat, lon


def assert_matches_mosaic(mosaic: Mosaic, path: Path, skip_hole: bool) -> None:
    """Imagery where the mosaic is, the same picture (correlation > 0.99), shifted by less than 0.1 px."""
    with rasterio.open(path) as ds:
        data, m_per_px = ds.read(), ds.res[0]
    rgb, alpha = data[:3].transpose(1, 2, 0).astype(np.float32), data[3]
    want, inside = expected(mosaic, path)
    valid = inside & (alpha == 255)
    if skip_hole:
        hole = np.zeros_like(valid)
        r, c = utm_pixel(path, *tile_centre(*HOLE))
        k = int(TILE_M / m_per_px * 0.75)  # the hole's tile, with its blended border
        hole[max(r - k, 0):r + k, max(c - k, 0):c + k] = True
        valid &= ~hole
    assert valid.mean() > 0.5
    corr = np.corrcoef(rgb[valid].ravel(), want[valid].ravel())[0, 1]
    assert corr > 0.99, corr
    # geolocation: the phase correlation of a window with imagery all over
    r0, c0 = utm_pixel(path, LAT - 0.0005, LON - 0.0012)
    k = int(60 / m_per_px)  # 60 m
    a, b = rgb[r0 - k:r0, c0:c0 + k].mean(axis=2), want[r0 - k:r0, c0:c0 + k].mean(axis=2)
    assert valid[r0 - k:r0, c0:c0 + k].all()
    (dx, dy), _ = cv2.phaseCorrelate(a.astype(np.float64), b.astype(np.float64))
    assert math.hypot(dx, dy) < 0.1, (dx, dy)


# ---------------------------------------------------------------------------------------------------- XYZ

def test_xyz_map_matches_the_mosaic_is_utm_tiled_compressed_with_alpha_and_cached(server: TileServer,
                                                                                 tmp_path: Path) -> None:
    out, cache = tmp_path / "area.tif", tmp_path / "cache"
    res = build_map(BBOX, f"{server.base}/ok/{{z}}/{{x}}/{{y}}.png", out, zoom=ZOOM, cache_dir=cache,
                    retry_delay_s=0.0, progress=False, user_agent="taco-mav-test/1")
    assert res.epsg == 32632 and res.zoom == ZOOM and res.path == out
    assert res.m_per_px == pytest.approx(xyz_ground_m_per_px(ZOOM, LAT), rel=1e-3)
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32632 and ds.count == 4 and ds.dtypes[0] == "uint8"
        assert ds.transform.b == 0 and ds.transform.d == 0 and ds.transform.e < 0  # north-up
        assert ds.block_shapes[0] == (512, 512) and ds.compression is Compression.deflate
        assert ds.colorinterp[3] is ColorInterp.alpha
        # the whole bbox is on the map
        E, N = UtmProjector(32632).to_utm(np.array([BBOX.south, BBOX.north]), np.array([BBOX.west, BBOX.east]))
        left, bottom, right, top = ds.bounds
        assert left <= E.min() and right >= E.max() and bottom <= N.min() and top >= N.max()
        alpha = ds.read(4)
    assert_matches_mosaic(server.mosaic, out, skip_hole=True)
    r, c = utm_pixel(out, *tile_centre(*HOLE))
    assert (alpha[r - 5:r + 5, c - 5:c + 5] == 0).all()  # the 404 tile is transparent
    r, c = utm_pixel(out, LAT, LON)
    assert (alpha[r - 5:r + 5, c - 5:c + 5] == 255).all()
    assert 0.8 < res.imagery_fraction < 0.97
    assert server.user_agents == {"taco-mav-test/1"}
    # the daemon's reader takes it
    with SatelliteMap(out) as sat:
        e, n = UtmProjector(32632).to_utm(LAT, LON)
        crop = sat.crop(np.array([e, n]), 0.3, 128, 0.4)
        assert crop.valid_fraction == pytest.approx(1.0)

    # a second run reads the cache: no tile that was served is asked again (the 404 tile is: GDAL caches images)
    served = {p for p, s in server.statuses.items() if p.startswith("/ok/") and s == 200}
    before = dict(server.requests)
    again = build_map(BBOX, f"{server.base}/ok/{{z}}/{{x}}/{{y}}.png", tmp_path / "again.tif", zoom=ZOOM,
                      cache_dir=cache, progress=False)
    assert len(served) >= 6
    assert all(server.requests[p] == before[p] for p in served)
    assert sum(server.requests.values()) - sum(before.values()) <= 1  # HOLE only
    with rasterio.open(out) as a, rasterio.open(again.path) as b:
        assert np.array_equal(a.read(), b.read())


def test_m_per_px_picks_the_zoom_and_the_resolution(server: TileServer, tmp_path: Path) -> None:
    res = build_map(BBOX, f"{server.base}/ok/{{z}}/{{x}}/{{y}}.png", tmp_path / "m.tif", m_per_px=0.5,
                    cache_dir=tmp_path / "cache", progress=False)
    assert res.zoom == ZOOM and res.m_per_px == 0.5  # z18 is 0.39 m/px here, z17 0.78
    with rasterio.open(res.path) as ds:
        assert ds.res == (0.5, 0.5)
        assert ds.transform.c % 0.5 == pytest.approx(0.0, abs=1e-6)  # snapped to the grid


def test_finer_than_the_tiles_in_several_windows(server: TileServer, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """--zoom and a finer --m-per-px: 4 windows of 1024 px, one progress bar."""
    res = build_map(BBOX, f"{server.base}/ok/{{z}}/{{x}}/{{y}}.png", tmp_path / "fine.tif", zoom=ZOOM,
                    m_per_px=0.2, cache_dir=tmp_path / "cache", progress=True)
    assert res.width > 1024 and res.height > 1024
    assert_matches_mosaic(server.mosaic, res.path, skip_hole=True)
    assert "map fine.tif" in capsys.readouterr().err


def test_dropped_and_late_tiles_are_read_again(server: TileServer, tmp_path: Path) -> None:
    out = tmp_path / "flaky.tif"
    build_map(BBOX, f"{server.base}/flaky/{{z}}/{{x}}/{{y}}.png", out, zoom=ZOOM, cache_dir=tmp_path / "c",
              timeout_s=1.0, retries=3, retry_delay_s=0.0, progress=False)
    assert_matches_mosaic(server.mosaic, out, skip_hole=False)
    assert max(n for p, n in server.requests.items() if p.startswith("/flaky/")) >= 2


# ---------------------------------------------------------------------------------------------------- WMTS, WMS

def test_wmts_source(server: TileServer, tmp_path: Path) -> None:
    out = tmp_path / "wmts.tif"
    res = build_map(BBOX, f"WMTS:{server.base}/wmts/WMTSCapabilities.xml,layer=test", out, cache_dir=tmp_path / "c",
                    progress=False)
    assert res.m_per_px == pytest.approx(xyz_ground_m_per_px(ZOOM, LAT), rel=0.01)
    assert_matches_mosaic(server.mosaic, out, skip_hole=True)


def test_wms_source(server: TileServer, tmp_path: Path) -> None:
    out = tmp_path / "wms.tif"
    build_map(BBOX, f"WMS:{server.base}/wms?LAYERS=test&KEY=abc", out, m_per_px=0.4, cache_dir=tmp_path / "c",
              progress=False)
    assert_matches_mosaic(server.mosaic, out, skip_hole=False)
    getmaps = [p for p in server.requests if p.startswith("/wms")]
    assert getmaps and all("KEY=abc" in p and "layers=test" in p.lower() for p in getmaps)  # its own key kept


# ---------------------------------------------------------------------------------------------------- errors

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_server(tmp_path: Path) -> None:
    url = f"http://127.0.0.1:{_free_port()}/{{z}}/{{x}}/{{y}}.png"
    with pytest.raises(MapSourceError, match=r"cannot reach the server") as err:
        build_map(BBOX, url, tmp_path / "x.tif", zoom=ZOOM, cache_dir=tmp_path / "c", retries=1,
                  retry_delay_s=0.0, progress=False)
    assert err.value.status == 0 and err.value.url.startswith(url.split("{")[0] + f"{ZOOM}/")
    assert not (tmp_path / "x.tif").exists() and not (tmp_path / "x.tif.part").exists()


def test_unreachable_wmts_capabilities(tmp_path: Path) -> None:
    url = f"http://127.0.0.1:{_free_port()}/WMTSCapabilities.xml"
    with pytest.raises(MapSourceError, match=r"cannot read the WMTS capabilities"):
        build_map(BBOX, f"WMTS:{url}", tmp_path / "x.tif", cache_dir=tmp_path / "c", progress=False)


def test_refused_tile_names_its_url(server: TileServer, tmp_path: Path) -> None:
    with pytest.raises(MapSourceError, match=r"/forbidden/18/\d+/\d+\.png: the server refused the tile \(HTTP 403\)"):
        build_map(BBOX, f"{server.base}/forbidden/{{z}}/{{x}}/{{y}}.png", tmp_path / "x.tif", zoom=ZOOM,
                  cache_dir=tmp_path / "c", retry_delay_s=0.0, progress=False)
    assert not (tmp_path / "x.tif").exists()


def test_no_tile_anywhere_is_an_error(server: TileServer, tmp_path: Path) -> None:
    with pytest.raises(MapSourceError, match=rf"/gone/18/{CX}/{CY}\.png: no imagery anywhere") as err:
        build_map(BBOX, f"{server.base}/gone/{{z}}/{{x}}/{{y}}.png", tmp_path / "x.tif", zoom=ZOOM,
                  cache_dir=tmp_path / "c", progress=False)
    assert err.value.status == 404 and not (tmp_path / "x.tif").exists()


def test_bbox_too_large_for_the_disk(server: TileServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(map_tiles, "_free_bytes", lambda folder: (100_000, 1))
    with pytest.raises(UsageError, match=r"--bbox .*needs about .* GB .* but 0\.00 GB are free"):
        build_map(BBOX, f"{server.base}/ok/{{z}}/{{x}}/{{y}}.png", tmp_path / "x.tif", zoom=ZOOM,
                  cache_dir=tmp_path / "c", progress=False)
    assert not [p for p in (tmp_path / "c").rglob("*") if p.is_file()]  # nothing was fetched before the check


# ---------------------------------------------------------------------------------------------------- a tile folder

def write_tile_folder(mosaic: Mosaic, folder: Path) -> None:
    """The mosaic's tiles as a local {z}/{x}/{y}.png folder (a tile cache), HOLE left out."""
    rows, cols = mosaic.image.shape[0] // 256, mosaic.image.shape[1] // 256
    for x in range(mosaic.x0, mosaic.x0 + cols):
        for y in range(mosaic.y0, mosaic.y0 + rows):
            if (x, y) != HOLE:
                (folder / str(ZOOM) / str(x)).mkdir(parents=True, exist_ok=True)
                (folder / str(ZOOM) / str(x) / f"{y}.png").write_bytes(_png(mosaic.tile(x, y)))


def test_a_local_tile_folder_through_a_file_template(tmp_path: Path) -> None:
    """A tile cache on disk is a source like a server: `file:///DIR/{z}/{x}/{y}.png`. The map matches the
    mosaic (geolocation within 0.1 px), the missing tile is transparent, an empty folder is a named error."""
    mosaic, tiles = make_mosaic(), tmp_path / "tiles"
    write_tile_folder(mosaic, tiles)
    out = tmp_path / "local.tif"
    res = build_map(BBOX, f"file://{tiles}/{{z}}/{{x}}/{{y}}.png", out, zoom=ZOOM, m_per_px=0.3,
                    cache_dir=tmp_path / "cache", progress=False)
    assert res.epsg == 32632 and res.zoom == ZOOM and res.m_per_px == 0.3
    assert 0.8 < res.imagery_fraction < 0.97
    assert_matches_mosaic(mosaic, out, skip_hole=True)
    with rasterio.open(out) as ds:
        alpha = ds.read(4)
    r, c = utm_pixel(out, *tile_centre(*HOLE))
    assert (alpha[r - 5:r + 5, c - 5:c + 5] == 0).all()
    (tmp_path / "empty").mkdir()
    with pytest.raises(MapSourceError, match=r"file://.*/empty/18/\d+/\d+\.png: no imagery anywhere in the bbox"):
        build_map(BBOX, f"file://{tmp_path / 'empty'}/{{z}}/{{x}}/{{y}}.png", tmp_path / "e.tif", zoom=ZOOM,
                  cache_dir=tmp_path / "cache", progress=False)


# ---------------------------------------------------------------------------------------------------- CLI

def test_cli(server: TileServer, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli.tif"
    argv = ["map", "--bbox", str(BBOX), "--source", f"{server.base}/ok/{{z}}/{{x}}/{{y}}.png", "--out", str(out),
            "--zoom", str(ZOOM), "--cache", str(tmp_path / "c"), "-q"]
    assert cli.main(argv) == 0
    assert "EPSG:32632" in capsys.readouterr().out and out.is_file()
    assert cli.main(argv) == 2  # an existing map is kept without --force
    assert "--force" in capsys.readouterr().err
    assert cli.main(["map", "--bbox", "49,8,49,9", "--source", "https://x/{z}/{x}/{y}.png", "--out",
                     str(tmp_path / "y.tif"), "--zoom", "18"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("taco-mav map: error: --bbox 49,8,49,9: an empty area")
