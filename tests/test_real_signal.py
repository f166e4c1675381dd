"""The real pairs' signal diagnostic (bench/real_signal.py): on panoramas rendered from a textured mosaic the truth
ranks on top and the best position is the truth; a set whose panoramas face another way than it says loses it;
on the real pairs in ../shared (skipped where absent) the dense channels are near chance."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from taco_mav.bench import real_signal
from taco_mav.bench.classical import textured_mosaic
from taco_mav.errors import DataError

REAL_PAIRS = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_pairs"
M0 = 0.2  # the mosaic's m/px
M_AERIAL = 0.5711  # the aerial's, as CVACT's
HEIGHT_M = 2.5
PANO_W, PANO_H = 512, 256  # CVACT's panoramas: 0.7 deg a pixel


def panorama_at(mosaic: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """An equirectangular panorama (column 0's left edge facing south, clockwise, rows 90 to -90 deg) of the flat
    mosaic seen from HEIGHT_M above its pixel (cx, cy); above the horizon a plain sky."""
    bearing = np.radians(180.0 + (np.arange(PANO_W) + 0.5) / PANO_W * 360.0)[None, :]
    elev = np.radians(90.0 - (np.arange(PANO_H) + 0.5) / PANO_H * 180.0)[:, None]
    ground = elev < -1e-3
    rng = np.where(ground, HEIGHT_M / np.tan(np.maximum(-elev, 1e-3)), 0.0) * np.ones_like(bearing)
    map_x = (cx + rng * np.sin(bearing) / M0).astype(np.float32)
    map_y = (cy - rng * np.cos(bearing) / M0).astype(np.float32)
    pano = cv2.remap(mosaic, map_x, map_y, cv2.INTER_AREA, borderMode=cv2.BORDER_REFLECT)
    pano[~np.broadcast_to(ground, pano.shape[:2])] = (200, 210, 235)
    return pano


def write_synthetic_set(folder: Path, places: int = 3, col0_bearing_deg: float = 180.0, seed: int = 4) -> Path:
    """A panorama set of `places` places on one textured mosaic, written in the real pairs' format; its pairs.json
    says column 0 faces col0_bearing_deg (the panoramas are rendered facing 180)."""
    mosaic = textured_mosaic(seed, 2000, M0)
    rng = np.random.default_rng(seed)
    side = 256
    scale = M0 / M_AERIAL
    folder.mkdir(parents=True, exist_ok=True)
    pairs = []
    for k in range(places):
        cx, cy = (float(v) for v in rng.uniform(side / scale / 2 + 10, 2000 - side / scale / 2 - 10, 2))
        M = np.array([[1 / scale, 0.0, cx - side / 2 / scale], [0.0, 1 / scale, cy - side / 2 / scale]])
        aerial = cv2.warpAffine(mosaic, M, (side, side), flags=cv2.INTER_AREA | cv2.WARP_INVERSE_MAP)
        cv2.imwrite(str(folder / f"g{k}.png"), cv2.cvtColor(panorama_at(mosaic, cx, cy), cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / f"a{k}.png"), cv2.cvtColor(aerial, cv2.COLOR_RGB2BGR))
        pairs.append({"id": f"p{k}", "ground": f"g{k}.png", "aerial": f"a{k}.png", "truth_px": [128.0, 128.0]})
    meta = {"set": folder.name, "camera_height_m": HEIGHT_M,
            "ground": {"type": "panorama", "width": PANO_W, "height": PANO_H, "col0_bearing_deg": col0_bearing_deg,
                       "clockwise": True, "el_top_deg": 90.0, "el_bottom_deg": -90.0},
            "aerial": {"north_up": True, "m_per_px": M_AERIAL, "m_per_px_uncertainty": 0.0}, "pairs": pairs}
    (folder / "pairs.json").write_text(json.dumps(meta))
    return folder


def test_on_rendered_panoramas_the_truth_ranks_on_top(tmp_path: Path) -> None:
    keys = real_signal.evaluate(write_synthetic_set(tmp_path / "synthetic"))
    assert keys["real_signal_views_fov360"] == 3 and keys["real_signal_views_fov90"] == 12
    assert keys["real_signal_chance_within_3m_share"] == pytest.approx(math.pi * 3.0 ** 2 / 30.0 ** 2, rel=0.15)
    for descriptor in ("grey", "orientation"):
        for fov in (360, 90):
            prefix = f"real_signal_luma_{descriptor}_fov{fov}"
            assert keys[f"{prefix}_truth_percentile"] >= 0.99, prefix
            # all round every place; a 90 deg wedge 10-11 of the 12 (a wedge of plain ground is ambiguous)
            assert keys[f"{prefix}_within_3m_share"] >= (0.99 if fov == 360 else 0.75), prefix
            assert keys[f"{prefix}_median_error_m"] <= 1.0, prefix


def test_panoramas_that_face_another_way_than_their_set_says_lose_the_truth(tmp_path: Path) -> None:
    # the same places, pairs.json wrong about which way column 0 faces by a quarter turn
    keys = real_signal.evaluate(write_synthetic_set(tmp_path / "turned", col0_bearing_deg=90.0))
    for descriptor in ("grey", "orientation"):
        prefix = f"real_signal_luma_{descriptor}_fov360"
        assert keys[f"{prefix}_within_3m_share"] <= 0.1, prefix
        assert keys[f"{prefix}_median_error_m"] >= 3.0, prefix


def test_an_aerial_too_small_for_the_search_is_refused_by_name(tmp_path: Path) -> None:
    folder = write_synthetic_set(tmp_path / "small", places=1)
    meta = json.loads((folder / "pairs.json").read_text())
    meta["pairs"][0]["truth_px"] = [40.0, 128.0]  # 23 m from the aerial's west edge: 16 m of ground + 15 m search
    (folder / "pairs.json").write_text(json.dumps(meta))
    with pytest.raises(DataError, match="does not hold 16 m of ground plus 15 m of search"):
        real_signal.evaluate(folder)


def test_the_real_pairs_dense_channels_are_near_chance() -> None:
    if not (REAL_PAIRS / "cvact" / "pairs.json").is_file():
        pytest.skip(f"real pairs not found at {REAL_PAIRS} (expected ../shared/data/real_pairs beside the repo)")
    keys = real_signal.run(real_pairs=REAL_PAIRS)
    assert keys["real_signal_views_fov360"] == 12 and keys["real_signal_views_fov90"] == 48
    # docs/matchers.md: no channel places a forward camera's wedge; all round, at most 2 of the 12 places
    wedge = [v for k, v in keys.items() if k.endswith("fov90_within_3m_share")]
    whole = [v for k, v in keys.items() if k.endswith("fov360_within_3m_share")]
    assert len(wedge) == 6 and max(wedge) <= 0.1
    assert len(whole) == 6 and max(whole) <= 0.25
    # the truth ranks at most a little above the middle of the searched positions
    assert max(v for k, v in keys.items() if k.endswith("_truth_percentile")) <= 0.8
