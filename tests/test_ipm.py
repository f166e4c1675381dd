"""Inverse perspective mapping puts ground points at their metric BEV pixels and agrees with the true map."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rasterio.transform import from_origin

from taco_mav.bench.classical import textured_mosaic
from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig
from taco_mav.cvgl.ipm import BevProjector
from taco_mav.datasets.synthetic.render import GroundRenderer
from taco_mav.errors import DataError

E0, N0, RES = 600_000.0, 5_400_000.0, 0.2


@pytest.fixture(scope="module")
def camera() -> GroundCamera:
    return GroundCamera.from_config(CameraConfig())


def test_pixel_ground_round_trip_and_default_vehicle_pixel(camera: GroundCamera) -> None:
    bev = BevProjector(camera, (101, 80), 0.5, 40.0)
    assert bev.vehicle_px == (50.0, 79.0)
    fl = np.array([[10.0, 2.0], [25.5, -7.25]])
    px = bev.pixel_of_ground(fl)
    np.testing.assert_allclose(px, [[46.0, 59.0], [64.5, 28.0]])
    np.testing.assert_allclose(bev.ground_of_pixel(px), fl)
    # The view wedge: nothing behind the camera or nearer than the bottom image row sees (about 5.9 m).
    fwd_near = camera.mount_height_m * camera.K[1, 1] / (camera.height - 1 - camera.K[1, 2])
    assert not bev.mask[bev.fwd_m < fwd_near - 0.5].any()
    assert bev.mask[(bev.fwd_m > fwd_near + 1.0) & (bev.fwd_m < 30) & (np.abs(bev.left_m) < 2)].all()


def test_painted_ground_point_lands_on_its_bev_pixel(camera: GroundCamera) -> None:
    img = np.zeros((camera.height, camera.width), np.float32)
    fl = np.array([[12.0, -3.0]])
    (u, v), _ = camera.project(fl)[0][0], None
    img[int(round(v)) - 1: int(round(v)) + 2, int(round(u)) - 6: int(round(u)) + 7] = 100.0
    bev = BevProjector(camera, 200, 0.2, 40.0, vehicle_px=(99.5, 199.0))
    out, mask = bev.project(img)
    ys, xs = np.nonzero(out > 1.0)
    w = out[ys, xs]
    centroid = np.array([np.sum(xs * w) / w.sum(), np.sum(ys * w) / w.sum()])
    np.testing.assert_allclose(centroid, bev.pixel_of_ground(fl)[0], atol=1.0)
    assert out.dtype == np.float32 and out.shape == (200, 200) and mask.shape == (200, 200)


def test_bev_of_rendered_view_matches_the_map(camera: GroundCamera) -> None:
    mosaic = textured_mosaic(3, 1000, RES)
    transform = from_origin(E0, N0 + 1000 * RES, RES, RES)
    pose = (E0 + 100.0, N0 + 100.0, math.radians(37.0))
    view = GroundRenderer(mosaic, transform, camera, max_range_m=60.0, haze_m=None).render(pose)
    m = 0.4
    bev = BevProjector(camera, (121, 75), m, 25.0)
    out, mask = bev.project(view)
    import cv2

    def truth_corr(df: float, dl: float) -> float:
        """Correlation of the BEV with the mosaic sampled at each BEV pixel's ground point shifted (df, dl) m."""
        c, s = math.cos(pose[2]), math.sin(pose[2])
        f, l = bev.fwd_m + df, bev.left_m + dl
        E, N = pose[0] + c * f - s * l, pose[1] + s * f + c * l
        inv = ~transform
        col = (inv.a * E + inv.b * N + inv.c - 0.5).astype(np.float32)
        row = (inv.d * E + inv.e * N + inv.f - 0.5).astype(np.float32)
        truth = cv2.remap(mosaic.astype(np.float32), col, row, cv2.INTER_LINEAR)
        return float(np.corrcoef(out[mask].ravel(), truth[mask].ravel())[0, 1])

    best = truth_corr(0.0, 0.0)
    assert best > 0.8, best
    for df, dl in [(0.5, 0.0), (-0.5, 0.0), (0.0, 0.5), (0.0, -0.5)]:
        assert truth_corr(df, dl) < best - 0.02
    assert np.all(out[~mask] == 0.0)


def test_rejects_wrong_image_size(camera: GroundCamera) -> None:
    bev = BevProjector(camera, 64, 0.5, 30.0)
    with pytest.raises(DataError, match="camera model"):
        bev.project(np.zeros((10, 10), np.uint8))
