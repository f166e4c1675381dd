"""Real ground/aerial pairs (datasets/real_pairs.py): the set format read with errors that name the file and key,
pinhole views cut from a panorama at the bearing and elevation asked, and its ground seen from above."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from taco_mav.datasets.real_pairs import find_sets, ground_bev, load_set, pinhole_view
from taco_mav.errors import DataError

REAL_PAIRS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_pairs"
PANO = {"type": "panorama", "width": 720, "height": 360, "col0_bearing_deg": 180.0, "clockwise": True,
        "el_top_deg": 90.0, "el_bottom_deg": -90.0}


def coded_panorama() -> np.ndarray:
    """A panorama whose pixel holds its own bearing (channels 0 and 2: its cosine and sine, so that bilinear
    interpolation across north stays right) and elevation (channel 1, deg + 90), laid out by PANO."""
    W, H = PANO["width"], PANO["height"]
    cols = (np.arange(W) + 0.5) / W * 360.0 + PANO["col0_bearing_deg"]
    rows = 90.0 - (np.arange(H) + 0.5) / H * 180.0
    img = np.zeros((H, W, 3), np.float32)
    img[:, :, 0] = np.cos(np.radians(cols))[None, :]
    img[:, :, 2] = np.sin(np.radians(cols))[None, :]
    img[:, :, 1] = rows[:, None] + 90.0
    return img


def bearing_of(px: np.ndarray) -> float:
    return math.degrees(math.atan2(float(px[2]), float(px[0]))) % 360.0


@pytest.mark.parametrize("bearing", [0.0, 37.0, 180.0, 300.0])
def test_a_cut_view_looks_where_it_is_asked(bearing: float) -> None:
    pano = coded_panorama()
    view, cam = pinhole_view(pano, PANO, bearing, 90.0, 201, 151, 10.0, 2.5)
    cy, cx = 75, 100
    assert abs((bearing_of(view[cy, cx]) - bearing + 180.0) % 360.0 - 180.0) <= 0.6
    # the centre pixel looks 10 deg down; the right edge 45 deg right of the bearing (at the horizon row)
    assert float(view[cy, cx, 1]) - 90.0 == pytest.approx(-10.0, abs=0.6)
    horizon = int(round(cam.K[1, 2] - cam.K[1, 1] * math.tan(math.radians(10.0))))
    right = (bearing_of(view[horizon, 200]) - bearing) % 360.0
    assert right == pytest.approx(45.0, abs=0.8)
    assert cam.mount_height_m == 2.5 and cam.pitch_rad == pytest.approx(math.radians(10.0))
    assert cam.K[0, 0] == pytest.approx(100.5 / math.tan(math.radians(45.0)))


def test_the_north_view_wraps_the_seam_without_a_jump() -> None:
    # bearing 180 sits at the panorama's seam (column 0's left edge)
    view, _ = pinhole_view(coded_panorama(), PANO, 180.0, 20.0, 41, 21, 0.0, 2.5)
    b = np.array([bearing_of(px) for px in view[10]])
    assert np.all(np.abs(b - 180.0) <= 10.5) and np.all(np.diff(b) > 0)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.3, -0.45)])
def test_the_ground_from_above_holds_each_point_where_the_panorama_saw_it(offset: tuple[float, float]) -> None:
    # each pixel of the north-up view shows the panorama's ray to that point of the ground: its compass bearing
    # from the camera and the depression angle atan(h / range), the camera at the centre plus the offset
    m, size, h = 0.5, 80, 2.5
    bev, rng, bearing = ground_bev(coded_panorama(), PANO, h, m, size, offset)
    for x, y in ((40, 10), (70, 40), (41, 75), (12, 33), (55, 60)):
        east = (x + 0.5 - size / 2 - offset[0]) * m
        north = -(y + 0.5 - size / 2 - offset[1]) * m
        assert rng[y, x] == pytest.approx(math.hypot(east, north))
        want = math.degrees(math.atan2(east, north)) % 360.0
        assert bearing[y, x] == pytest.approx(want)
        assert abs((bearing_of(bev[y, x]) - want + 180.0) % 360.0 - 180.0) <= 0.5
        assert float(bev[y, x, 1]) - 90.0 == pytest.approx(-math.degrees(math.atan2(h, math.hypot(east, north))),
                                                          abs=0.5)


def write_set(folder: Path, meta: dict, images: tuple[str, ...] = ("g.png", "a.png")) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in images:
        cv2.imwrite(str(folder / name), np.zeros((8, 8, 3), np.uint8))
    (folder / "pairs.json").write_text(json.dumps(meta))
    return folder


def good_meta() -> dict:
    return {"set": "t", "ground": dict(PANO), "camera_height_m": 2.5,
            "aerial": {"north_up": True, "m_per_px": 0.5, "m_per_px_uncertainty": 0.2},
            "pairs": [{"id": "p", "ground": "g.png", "aerial": "a.png", "truth_px": [4.0, 4.0]}]}


def test_a_set_loads_and_a_folder_of_sets_is_found(tmp_path: Path) -> None:
    write_set(tmp_path / "one", good_meta())
    write_set(tmp_path / "two", good_meta())
    sets = find_sets(tmp_path)
    assert [s.folder.name for s in sets] == ["one", "two"]
    s = sets[0]
    assert s.is_panorama and s.m_per_px == 0.5 and s.pairs[0].truth_px == (4.0, 4.0)
    assert find_sets(tmp_path / "one")[0].name == "t"


@pytest.mark.parametrize("breakage, message", [
    (lambda m: m["aerial"].pop("m_per_px"), "missing key 'm_per_px'"),
    (lambda m: m["ground"].update(type="fisheye"), "ground.type 'fisheye'"),
    (lambda m: m["pairs"][0].update(truth_px=[1.0]), "truth_px must be two finite numbers"),
    (lambda m: m["pairs"][0].update(aerial="missing.png"), "aerial file"),
    (lambda m: m["aerial"].update(north_up=False), "north_up is false"),
    (lambda m: m["ground"].update(clockwise="yes"), "key 'clockwise' has str"),
])
def test_a_broken_set_names_the_file_and_key(tmp_path: Path, breakage, message: str) -> None:
    meta = good_meta()
    breakage(meta)
    folder = write_set(tmp_path / "bad", meta)
    with pytest.raises(DataError, match="pairs.json") as exc:
        load_set(folder)
    assert message in str(exc.value)


def test_a_folder_without_sets_is_refused(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no set"):
        find_sets(tmp_path)


def test_the_shared_cvact_set_reads() -> None:
    if not REAL_PAIRS.is_dir():
        pytest.skip(f"real pairs not found at {REAL_PAIRS} (expected ../shared/data/real_pairs beside the repo)")
    (cvact,) = [s for s in find_sets(REAL_PAIRS) if s.name == "cvact"]
    assert len(cvact.pairs) == 12 and cvact.is_panorama and cvact.m_per_px == pytest.approx(0.5711)
    assert all(p.sky_mask is not None and p.truth_px == (128.0, 128.0) for p in cvact.pairs)
