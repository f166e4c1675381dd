"""SatelliteMap: heading-up crops land painted features where the geometry says, off-map and CRS errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rasterio

from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.errors import MapError, OffMapError

E_LEFT, N_TOP, RES, SIZE = 456_000.0, 5_430_000.0, 0.25, 1200  # 300 m square in UTM 32N
CENTRE = np.array([E_LEFT + 150.0, N_TOP - 150.0])
DOT_OFFSET = np.array([12.0, 20.0])  # ENU metres from CENTRE to the red dot


def write_geotiff(path: Path, epsg: int = 32632, nodata_block: bool = False) -> Path:
    """A 300 m grey GeoTIFF with a red 3x3 px dot at CENTRE + DOT_OFFSET and a green one 10 m north of CENTRE."""
    img = np.full((3, SIZE, SIZE), 90, np.uint8)
    rng = np.random.default_rng(1)
    img += rng.integers(0, 20, size=img.shape, dtype=np.uint8)
    for off, colour in ((DOT_OFFSET, (255, 0, 0)), (np.array([0.0, 10.0]), (0, 255, 0))):
        E, N = CENTRE + off
        col, row = int((E - E_LEFT) / RES), int((N_TOP - N) / RES)  # the pixel containing the point
        for b in range(3):
            img[b, row - 1:row + 2, col - 1:col + 2] = colour[b]
    transform = rasterio.Affine(RES, 0.0, E_LEFT, 0.0, -RES, N_TOP)
    with rasterio.open(path, "w", driver="GTiff", width=SIZE, height=SIZE, count=3, dtype="uint8",
                       crs=f"EPSG:{epsg}", transform=transform) as dst:
        dst.write(img)
    return path


def dot_centre(image: np.ndarray, channel: int) -> np.ndarray:
    """(u, v) centroid of pixels dominated by one channel."""
    others = [c for c in range(3) if c != channel]
    mask = (image[:, :, channel] > 150) & (image[:, :, others[0]] < 100) & (image[:, :, others[1]] < 100)
    assert mask.sum() > 0, "feature not in crop"
    w = image[:, :, channel].astype(float) * mask
    v, u = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    return np.array([(w * u).sum() / w.sum(), (w * v).sum() / w.sum()])


def expected_uv(offset_en: np.ndarray, heading: float, size: int, m_per_px: float) -> np.ndarray:
    """Crop pixel of a point offset (ENU metres) from the crop centre, from the heading-up definition."""
    fwd = offset_en[0] * math.cos(heading) + offset_en[1] * math.sin(heading)
    left = -offset_en[0] * math.sin(heading) + offset_en[1] * math.cos(heading)
    c = (size - 1) / 2
    return np.array([c - left / m_per_px, c - fwd / m_per_px])


# The painted pixel's centre (not the requested point) is where the dot really is.
def painted_offset(off: np.ndarray) -> np.ndarray:
    E, N = CENTRE + off
    col, row = int((E - E_LEFT) / RES), int((N_TOP - N) / RES)
    return np.array([E_LEFT + (col + 0.5) * RES, N_TOP - (row + 0.5) * RES]) - CENTRE


@pytest.fixture(scope="module")
def tif(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_geotiff(tmp_path_factory.mktemp("sat") / "map.tif")


@pytest.mark.parametrize("in_memory", [True, False])
@pytest.mark.parametrize("heading_deg", [0.0, 37.0, 180.0])
def test_feature_lands_at_predicted_pixel(tif: Path, heading_deg: float, in_memory: bool) -> None:
    with SatelliteMap(tif, in_memory_max_mb=1e3 if in_memory else 0.0) as sat:
        assert sat.in_memory is in_memory
        h = math.radians(heading_deg)
        crop = sat.crop(CENTRE, h, 256, 0.2)
        assert crop.image.shape == (256, 256, 3) and crop.image.dtype == np.uint8
        assert crop.valid_fraction == pytest.approx(1.0)
        got = dot_centre(crop.image, 0)
        want = expected_uv(painted_offset(DOT_OFFSET), h, 256, 0.2)
        assert np.abs(got - want).max() <= 1.0
        # crop_to_world inverts the crop geometry: the found dot maps back to its UTM position (< 1 px).
        back = SatelliteMap.crop_to_world(crop, got[None])[0]
        assert np.linalg.norm(back - (CENTRE + painted_offset(DOT_OFFSET))) < 0.2


def test_north_feature_up_when_heading_north_right_when_heading_west(tif: Path) -> None:
    with SatelliteMap(tif) as sat:
        c = (256 - 1) / 2
        up = dot_centre(sat.crop(CENTRE, math.pi / 2, 256, 0.2).image, 1)
        # heading north: north is image-up -> same column, smaller row (10 m / 0.2 = 50 px up)
        assert abs(up[0] - c) <= 1.5 and up[1] < c - 45
        right = dot_centre(sat.crop(CENTRE, math.pi, 256, 0.2).image, 1)
        # heading west: left of the vehicle is south, so north is image-right, same row
        assert right[0] > c + 45 and abs(right[1] - c) <= 1.5


def test_pixel_of_and_bounds(tif: Path) -> None:
    with SatelliteMap(tif) as sat:
        assert sat.epsg == 32632 and sat.m_per_px == pytest.approx(RES)
        assert sat.bounds_utm == pytest.approx((E_LEFT, N_TOP - SIZE * RES, E_LEFT + SIZE * RES, N_TOP))
        col, row = sat.pixel_of(E_LEFT + 0.5 * RES, N_TOP - 2.5 * RES)
        assert (float(col), float(row)) == pytest.approx((0.0, 2.0))


def test_coarse_crop_uses_averaged_level(tif: Path) -> None:
    with SatelliteMap(tif) as sat:
        crop = sat.crop(CENTRE, 0.3, 128, 1.0)  # 4x coarser than the mosaic
        # a 3x3 px red dot averaged into a 1 m pixel stays visible but not saturated.
        assert crop.image[:, :, 0].max() > 110
        assert crop.valid_fraction == pytest.approx(1.0)


def test_off_map(tif: Path) -> None:
    with SatelliteMap(tif) as sat:
        with pytest.raises(OffMapError) as err:
            sat.crop(CENTRE + 1000.0, 0.0, 256, 0.2)
        assert err.value.valid_fraction == 0.0
        # a 51.2 m crop centred 10 m inside the east edge has (25.6 + 10) / 51.2 = 69.5 % on the map.
        edge = np.array([E_LEFT + SIZE * RES - 10.0, CENTRE[1]])
        with pytest.raises(OffMapError) as err:
            sat.crop(edge, 0.0, 256, 0.2)
        assert err.value.valid_fraction == pytest.approx(35.6 / 51.2, abs=0.01)
        crop = sat.crop(edge, 0.0, 256, 0.2, min_valid=0.5)
        assert crop.valid_fraction == pytest.approx(35.6 / 51.2, abs=0.01)
        # heading east: image-up is east, so the top rows are off the map and zero.
        assert crop.image[:20].max() == 0 and crop.image[-20:].min() > 0


def test_non_utm_crs_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "wgs84.tif"
    with rasterio.open(path, "w", driver="GTiff", width=8, height=8, count=3, dtype="uint8", crs="EPSG:4326",
                       transform=rasterio.Affine(1e-5, 0, 8.4, 0, -1e-5, 49.0)) as dst:
        dst.write(np.zeros((3, 8, 8), np.uint8))
    with pytest.raises(MapError, match=r"wgs84\.tif.*EPSG:4326.*UTM"):
        SatelliteMap(path)
    with pytest.raises(MapError, match="not found"):
        SatelliteMap(tmp_path / "missing.tif")


def test_crops_from_the_block_cache_are_the_in_memory_crops_and_the_cache_stays_bounded(tif: Path) -> None:
    """At the mosaic's resolution (pyramid level 0, the daemon's crops) the blocks read in windows give the same
    pixels as the mosaic read whole, byte for byte, with blocks evicted and read again as well; the LRU holds at
    most its capacity (default 64 blocks, 16 MB)."""
    rng = np.random.default_rng(3)
    with SatelliteMap(tif) as whole, SatelliteMap(tif, in_memory_max_mb=0.0) as windows, \
            SatelliteMap(tif, in_memory_max_mb=0.0, cache_blocks=4) as small:
        assert whole.in_memory and not windows.in_memory and windows._cache_blocks == 64
        for _ in range(12):
            centre = CENTRE + rng.uniform(-60.0, 60.0, 2)
            heading = float(rng.uniform(-math.pi, math.pi))
            a = whole.crop(centre, heading, 512, RES)
            for b in (windows.crop(centre, heading, 512, RES), small.crop(centre, heading, 512, RES)):
                np.testing.assert_array_equal(a.image, b.image)
                assert a.valid_fraction == b.valid_fraction == 1.0
        assert len(windows._blocks) == 20  # the 1200 px map's 25 blocks, of which the crops touch 20
        assert len(small._blocks) == 4


_DRIVE_ACROSS = """
import sys
from pathlib import Path
import numpy as np
from taco_mav.cvgl.satellite import SatelliteMap

def rss_mb():
    status = Path("/proc/self/status").read_text().splitlines()
    return int(next(line for line in status if line.startswith("VmRSS")).split()[1]) / 1024

with SatelliteMap(sys.argv[1], in_memory_max_mb=0.0, cache_blocks=4) as sat:
    E0, N0, E1, N1 = sat.bounds_utm
    sat.crop(np.array([E0 + 60.0, N1 - 60.0]), 0.0, 256, 0.25)
    before = rss_mb()
    for N in np.arange(N0 + 60.0, N1 - 60.0, 50.0):
        for E in np.arange(E0 + 60.0, E1 - 60.0, 50.0):
            sat.crop(np.array([E, N]), 0.3, 256, 0.25)
    print(rss_mb() - before)
"""


def test_a_drive_across_a_large_mosaic_does_not_grow_gdals_cache(tmp_path: Path) -> None:
    """Crops across all of a 4000 x 4000 px mosaic read all its 48 MB of pixels once. GDAL would keep every file block
    it decoded (its cache defaults to 5 % of the RAM); capped at GDAL_CACHE_MB the process grows by far less than the
    mosaic (without the cap, as before, it grew 60 MB here; with it 1-12 MB)."""
    import subprocess
    import sys

    from taco_mav.cvgl.satellite import GDAL_CACHE_MB

    n = 4000
    yy, xx = np.mgrid[0:n, 0:n]
    img = np.stack([(xx // 7 + yy // 5) % 256, (xx // 3) % 256, (yy // 3) % 256]).astype(np.uint8)
    path = tmp_path / "large.tif"
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=3, dtype="uint8", crs="EPSG:32632",
                       transform=rasterio.Affine(0.25, 0.0, E_LEFT, 0.0, -0.25, N_TOP), tiled=True,
                       blockxsize=512, blockysize=512, compress="deflate") as dst:
        dst.write(img)
    del img, yy, xx
    out = subprocess.run([sys.executable, "-c", _DRIVE_ACROSS, str(path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    grown = float(out.stdout.split()[-1])
    assert grown < GDAL_CACHE_MB + 12.0, grown
