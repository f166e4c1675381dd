"""The flat-world renderer puts mosaic points where the pinhole model says and draws sky above the horizon."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rasterio.transform import from_origin

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig
from taco_mav.datasets.synthetic.render import GroundRenderer
from taco_mav.errors import DataError

E0, N0, RES = 600_000.0, 5_400_000.0, 0.2


def _world(size: int = 1500) -> tuple[np.ndarray, object]:
    mosaic = np.full((size, size, 3), 60, np.uint8)
    transform = from_origin(E0, N0 + size * RES, RES, RES)  # north-up, 0.2 m/px
    return mosaic, transform


def _diff_centroid(img: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(u, v) centroid of the brightness added to `ref`, weighted by the difference."""
    w = np.clip(img[..., 1].astype(np.float64) - ref[..., 1], 0.0, None)
    vs, us = np.nonzero(w)
    ww = w[vs, us]
    return np.array([np.sum(us * ww) / ww.sum(), np.sum(vs * ww) / ww.sum()])


@pytest.mark.parametrize("pitch", [0.0, 0.05])
def test_painted_point_lands_where_projection_predicts(pitch: float) -> None:
    mosaic, transform = _world()
    cam = GroundCamera.from_config(CameraConfig(pitch_rad=pitch))
    pose = (E0 + 150.0, N0 + 150.0, math.radians(123.0))
    ref = GroundRenderer(mosaic, transform, cam, max_range_m=80.0, haze_m=None).render(pose)
    for fwd, left in [(8.0, 1.5), (12.0, -2.0), (6.0, 0.3)]:
        E = pose[0] + math.cos(pose[2]) * fwd - math.sin(pose[2]) * left
        N = pose[1] + math.sin(pose[2]) * fwd + math.cos(pose[2]) * left
        col, row = (~transform) @ (E, N)
        ci, ri = int(math.floor(col)), int(math.floor(row))
        painted = mosaic.copy()
        painted[ri, ci] = (255, 255, 255)
        # The painted pixel's centre in world metres and then in the vehicle frame.
        Ec, Nc = transform @ (ci + 0.5, ri + 0.5)
        dE, dN = Ec - pose[0], Nc - pose[1]
        c, s = math.cos(pose[2]), math.sin(pose[2])
        fl = np.array([[c * dE + s * dN, -s * dE + c * dN]])
        uv_pred, in_front = cam.project(fl)
        assert in_front[0]
        img = GroundRenderer(painted, transform, cam, max_range_m=80.0, haze_m=None).render(pose)
        uv = _diff_centroid(img, ref)
        assert np.abs(uv - uv_pred[0]).max() <= 1.0, (fwd, left, uv, uv_pred[0])


def test_horizon_and_above_is_sky_and_ground_below() -> None:
    mosaic, transform = _world()
    cam = GroundCamera.from_config(CameraConfig())
    sky = (110, 150, 210)
    img = GroundRenderer(mosaic, transform, cam, max_range_m=80.0, sky_rgb=sky, haze_m=None).render(
        (E0 + 150.0, N0 + 150.0, 0.3))
    horizon = int(math.floor(cam.K[1, 2]))  # pitch 0: the horizon is the principal row
    assert img.shape == (cam.height, cam.width, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img[0, 0], sky)
    # Sky rows are bluish (B > R), the ground below is the mosaic's grey 60.
    assert np.all(img[: horizon + 1, :, 2] > img[: horizon + 1, :, 0])
    np.testing.assert_array_equal(img[horizon + 40 :], 60)


def test_off_mosaic_ground_uses_fill_colour_and_haze_blends_toward_horizon() -> None:
    mosaic, transform = _world(200)
    cam = GroundCamera.from_config(CameraConfig())
    r = GroundRenderer(mosaic, transform, cam, max_range_m=60.0, fill_rgb=(10, 20, 30), haze_m=None)
    far = r.render((E0 - 500.0, N0 - 500.0, 0.0))  # nowhere near the mosaic
    np.testing.assert_array_equal(far[-1], np.tile([10, 20, 30], (cam.width, 1)))
    hazy = GroundRenderer(mosaic, transform, cam, max_range_m=60.0, haze_m=20.0).render((E0 + 20, N0 + 20, 0.0))
    bottom, near_horizon = hazy[-1, 600].astype(int), hazy[cam.height // 2 + 3, 600].astype(int)
    assert bottom[0] < near_horizon[0]  # farther ground is hazier (closer to the bright horizon colour)


def test_rejects_bad_mosaic() -> None:
    cam = GroundCamera.from_config(CameraConfig())
    with pytest.raises(DataError, match="uint8 RGB"):
        GroundRenderer(np.zeros((10, 10), np.uint8), from_origin(0, 0, 1, 1), cam)
