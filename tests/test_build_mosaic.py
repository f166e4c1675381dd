"""tools/build_mosaic.py: XYZ tiles -> UTM GeoTIFF puts a painted feature at its true UTM position."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from pyproj import Transformer

from taco_mav.cvgl.satellite import SatelliteMap

spec = importlib.util.spec_from_file_location("build_mosaic", Path(__file__).parents[1] / "tools" / "build_mosaic.py")
build_mosaic_mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
spec.loader.exec_module(build_mosaic_mod)  # type: ignore[union-attr]

ZOOM, LAT, LON = 19, 49.0105, 8.4035  # Karlsruhe
DOT = (49.01062, 8.40371)  # the red dot, WGS84 degrees


def write_tiles(folder: Path) -> None:
    """A 3x3 block of grey tiles around (LAT, LON) with a 3x3 px red dot centred on DOT."""
    cx, cy = build_mosaic_mod.tile_xy(LAT, LON, ZOOM)
    dx, dy = build_mosaic_mod.tile_xy(*DOT, ZOOM)
    for x in range(int(cx) - 1, int(cx) + 2):
        for y in range(int(cy) - 1, int(cy) + 2):
            img = np.full((256, 256, 3), 100, np.uint8)
            px, py = (dx - x) * 256 - 0.5, (dy - y) * 256 - 0.5  # pixel-centre coordinates inside this tile
            if 1 <= px < 255 and 1 <= py < 255:
                img[int(round(py)) - 1:int(round(py)) + 2, int(round(px)) - 1:int(round(px)) + 2] = (0, 0, 255)  # BGR
            (folder / str(ZOOM) / str(x)).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(folder / str(ZOOM) / str(x) / f"{y}.png"), img)


def test_feature_lands_at_utm_position(tmp_path: Path) -> None:
    write_tiles(tmp_path / "tiles")
    out = tmp_path / "mosaic.tif"
    rc = build_mosaic_mod.main(["--tiles", str(tmp_path / "tiles"), "--zoom", "19", "--bbox",
                                f"{LAT - 0.0004},{LON - 0.0006},{LAT + 0.0004},{LON + 0.0006}", "--out", str(out),
                                "--m-per-px", "0.15"])
    assert rc == 0
    with SatelliteMap(out) as sat:
        assert sat.epsg == 32632 and sat.m_per_px == pytest.approx(0.15)
        E, N = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(DOT[1], DOT[0])
        crop = sat.crop(np.array([E, N]), math.pi / 2, 64, 0.15)
        img = crop.image.astype(float)
        red = np.clip(img[:, :, 0] - img[:, :, 1], 0, None)
        v, u = np.mgrid[0:64, 0:64]
        got = np.array([(red * u).sum() / red.sum(), (red * v).sum() / red.sum()])
        # the tile pixel is ~0.2 m: the dot must be within one output pixel of the crop centre.
        assert np.abs(got - 31.5).max() <= 1.0, got
        assert crop.valid_fraction == pytest.approx(1.0)


def test_no_tiles_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="no tiles"):
        build_mosaic_mod.build_mosaic(tmp_path, 19, (LAT, LON, LAT + 0.001, LON + 0.001), tmp_path / "x.tif")
