"""The appearance-gap generator: deterministic, and it changes what it says it changes."""

from __future__ import annotations

import numpy as np

from taco_mav.bench.classical import textured_mosaic
from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig
from taco_mav.datasets.synthetic.gap import FrameGap, MapGap, alter_mosaic, occlude_frame


def test_alter_mosaic_is_seeded_and_changes_the_map() -> None:
    rgb = textured_mosaic(1, 400, 0.2)
    a, b = alter_mosaic(rgb, 0.2, seed=4), alter_mosaic(rgb, 0.2, seed=4)
    assert a.shape == rgb.shape and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, alter_mosaic(rgb, 0.2, seed=5))  # shadows move with the seed
    assert np.abs(a.astype(int) - rgb).mean() > 20


def test_fold_reverses_the_brightness_order_of_dark_materials() -> None:
    """Two flat materials darker than the fold point swap order: asphalt (60) below soil (100) becomes above it."""
    rgb = np.zeros((40, 80, 3), np.uint8)
    rgb[:, :40], rgb[:, 40:] = 60, 100
    gap = MapGap(gain=1.0, gamma=1.0, season="none", shadows_per_km2=0, resolution_m=0.2, blur_m=0.0, fold=0.6)
    out = alter_mosaic(rgb, 0.2, seed=0, gap=gap).astype(int)
    assert out[20, 10, 0] > out[20, 70, 0] + 20


def test_occluders_stand_on_the_ground_and_are_returned_as_a_mask() -> None:
    cam = GroundCamera.from_config(CameraConfig())
    frame = np.full((cam.height, cam.width, 3), 128, np.uint8)
    out, mask = occlude_frame(frame, cam, seed=2, gap=FrameGap(count=2))
    assert mask.any() and mask.shape == frame.shape[:2]
    assert (out[~mask] == 128).all() and (out[mask] != 128).any(axis=-1).mean() > 0.9
    # every box's foot is below the horizon (row cy for a level camera): it stands on the ground
    rows = np.flatnonzero(mask.any(axis=1))
    assert rows.max() > cam.K[1, 2]
    np.testing.assert_array_equal(out, occlude_frame(frame, cam, seed=2, gap=FrameGap(count=2))[0])
