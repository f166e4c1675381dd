"""taco_mav/datasets/map_sources.py: --bbox and --source parsed, the service descriptions GDAL's WMS driver reads
(network settings, cache, the XYZ grid, a WMS grid snapped so that overlapping areas share requests), and GDAL's
error chains read back into errors that name the tile's URL. The server-backed tests are in test_map_tiles.py."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from taco_mav.datasets.map_sources import (BBox, Failure, GdalHttp, SourceKind, parse_source, read_failure,
                                           service_xml, source_error, xyz_ground_m_per_px, xyz_tile)
from taco_mav.errors import UsageError

HTTP = GdalHttp(Path("/tmp/tiles & co"), connections=3, user_agent="me <test>", timeout_s=12.0)
BOX = BBox.from_corners(49.0, 8.40, 49.01, 8.42)


@pytest.mark.parametrize("text, needle", [
    ("49.0,8.4,49.0,8.5", "empty area"),
    ("49.0,8.4,49.1", "expected LAT0,LON0,LAT1,LON1"),
    ("86,8.4,87,8.5", "within [-80, 84]"),
    ("49,8,49.1,200", "within [-80, 84]"),
    ("40,8,49.1,9", "spans more than 6 degrees"),
    ("a,b,c,d", "expected LAT0,LON0,LAT1,LON1"),
])
def test_invalid_bbox(text: str, needle: str) -> None:
    with pytest.raises(UsageError, match=re.escape(needle)):
        BBox.parse(text)


@pytest.mark.parametrize("text, kind", [
    ("https://t.example/{z}/{x}/{y}.png", SourceKind.XYZ), ("https://t.example/${z}/${x}/${y}.jpg", SourceKind.XYZ),
    ("https://t.example/{z}/{x}/{-y}.png", SourceKind.XYZ),
    ("WMTS:https://w.example/WMTSCapabilities.xml,layer=ortho", SourceKind.WMTS),
    ("wms:https://w.example/wms?layers=dop&styles=", SourceKind.WMS),
])
def test_parse_source(text: str, kind: SourceKind) -> None:
    src = parse_source(text)
    assert src.kind is kind
    if kind is SourceKind.XYZ:
        assert src.tile_url(3, 1, 2).startswith("https://t.example/3/1/")
        assert src.tile_url(3, 1, 2).split("/")[-1].split(".")[0] == ("5" if "{-y}" in text else "2")


@pytest.mark.parametrize("text", ["https://t.example/tiles.png", "WMS:https://w.example/wms?styles=",
                                  "ftp://t.example/{z}/{x}/{y}.png", "WMTS:https://w.example/c.xml,colour=red"])
def test_bad_source_is_a_usage_error(text: str) -> None:
    with pytest.raises(UsageError, match=r"--source"):
        parse_source(text)


def test_xyz_xml_tells_gdal_the_network_and_the_cache() -> None:
    src = parse_source("https://t.example/{z}/{x}/{y}.png?key=a&b=c")
    root = ET.fromstring(service_xml(src, BOX, 19, None, HTTP))
    assert root.tag == "GDAL_WMS" and root.find("Service").get("name") == "TMS"
    assert root.findtext("Service/ServerUrl") == "https://t.example/${z}/${x}/${y}.png?key=a&b=c"
    assert root.findtext("DataWindow/TileLevel") == "19" and root.findtext("DataWindow/YOrigin") == "top"
    assert root.findtext("MaxConnections") == "3" and root.findtext("Timeout") == "12"
    assert root.findtext("UserAgent") == "me <test>" and root.findtext("ZeroBlockHttpCodes") == "204,404"
    assert root.findtext("Cache/Path") == "/tmp/tiles & co" and int(root.findtext("Cache/Expires")) > 7 * 86400
    assert root.findtext("OverviewCount") == "0" and root.findtext("BandsCount") == "4"
    tms = ET.fromstring(service_xml(parse_source("https://t.example/{z}/{x}/{-y}.png"), BOX, 19, None, HTTP))
    assert tms.findtext("DataWindow/YOrigin") == "bottom"


def test_wmts_xml() -> None:
    src = parse_source("WMTS:https://w.example/WMTSCapabilities.xml?x=1,layer=ortho,tilematrixset=g")
    root = ET.fromstring(service_xml(src, BOX, 17, None, HTTP))
    assert root.tag == "GDAL_WMTS"
    assert root.findtext("GetCapabilitiesUrl") == "https://w.example/WMTSCapabilities.xml?x=1"
    assert (root.findtext("Layer"), root.findtext("TileMatrixSet"), root.findtext("ZoomLevel")) == ("ortho", "g", "17")
    assert root.findtext("Cache/Path") == "/tmp/tiles & co" and root.findtext("UserAgent") == "me <test>"


def test_wms_xml_keeps_the_services_own_parameters_and_snaps_its_grid() -> None:
    src = parse_source("WMS:https://w.example/wms?SERVICE=WMS&LAYERS=dop&token=s3&BBOX=1,2,3,4&VERSION=1.3.0")
    assert src.url == "https://w.example/wms?token=s3" and src.param("layers") == "dop"
    a = ET.fromstring(service_xml(src, BOX, None, 0.5, HTTP))
    assert a.findtext("Service/CRS") == "EPSG:3857" and a.findtext("Service/Version") == "1.3.0"
    b = ET.fromstring(service_xml(src, BBox.from_corners(49.001, 8.401, 49.012, 8.43), None, 0.5, HTTP))
    for root in (a, b):  # whole blocks of 512 px, on one grid
        x0, x1 = float(root.findtext("DataWindow/UpperLeftX")), float(root.findtext("DataWindow/LowerRightX"))
        step = (x1 - x0) / int(root.findtext("DataWindow/SizeX")) * 512
        assert round(x0 / step, 6) == round(x0 / step) and round((x1 - x0) / step, 6) == round((x1 - x0) / step)
    assert float(a.findtext("DataWindow/UpperLeftX")) == float(b.findtext("DataWindow/UpperLeftX"))


def test_xyz_helpers() -> None:
    assert xyz_ground_m_per_px(0, 0.0) == pytest.approx(156543.03, abs=0.01)
    assert xyz_ground_m_per_px(19, 49.0105) == pytest.approx(0.196, abs=0.001)
    assert xyz_tile(0.0, 0.0, 1) == (1, 1) and xyz_tile(85.0, -180.0, 3) == (0, 0)


def _chain(*texts: str) -> Exception:
    exc: Exception | None = None
    for text in reversed(texts):
        new = RuntimeError(text)
        new.__cause__ = exc
        exc = new
    assert exc is not None
    return exc


@pytest.mark.parametrize("status, error, transient, needle", [
    (403, "(null)", False, "refused the tile (HTTP 403)"),
    (0, "Failed to connect to h port 1 after 0 ms: Could not connect to server", True, "cannot reach the server"),
    (0, "Operation timed out after 1000 milliseconds with 0 bytes received", True, "no answer after 4 tries"),
    (503, "(null)", True, "HTTP 503 after 4 tries"),
])
def test_gdal_errors_are_read_and_named(status: int, error: str, transient: bool, needle: str) -> None:
    exc = _chain("Read failed. See previous exception for details.",
                 f"GDALWMS: Unable to download block 70, 42.\nURL: \n  HTTP status code: {status}, error: {error}.\n"
                 "Add the HTTP status code to <ZeroBlockHttpCodes> to ignore this error (see ...).",
                 "GDALWMS: Unable to open downloaded block.")
    failure = read_failure(exc)
    assert (failure.status, failure.block, failure.transient) == (status, (70, 42), transient)
    src = parse_source("https://t.example/{z}/{x}/{y}.png")
    err = source_error(failure, src, 7, HTTP, tries=4)
    assert needle in str(err) and str(err).startswith("https://t.example/7/70/42.png: ")
    assert err.url == "https://t.example/7/70/42.png" and err.status == status
    wmts = source_error(failure, parse_source("WMTS:https://w.example/c.xml,layer=o"), 7, HTTP, tries=4)
    assert str(wmts).startswith("WMTS https://w.example/c.xml layer o (block 70, 42): ")


def test_an_unknown_failure_keeps_gdals_words() -> None:
    failure = read_failure(_chain("Read failed.", "GDALWMS: The server returned unknown exception."))
    assert failure.status is None and not failure.transient
    assert "GDALWMS: The server returned unknown exception" in str(source_error(failure, parse_source(
        "WMS:https://w.example/wms?LAYERS=a"), None, HTTP, tries=1))
