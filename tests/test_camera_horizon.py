"""Mount pitch and height: the horizon of rendered world frames against the profile's pitch (right and
misconfigured, through a distorting lens too), the rate-limited warning, and height/pitch from ground marks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from rasterio.transform import from_origin

from taco_mav.bench.classical import textured_mosaic
from taco_mav.camera.calibration import FrameRectifier, LensCalibration, LensModel, pinhole_matrix
from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.horizon import HorizonCheck, horizon_row, mount_from_marks
from taco_mav.config import CameraConfig
from taco_mav.datasets.synthetic.render import GroundRenderer, LensRenderer
from taco_mav.errors import ConfigError

WEST, NORTH, RES = 500_000.0, 5_430_000.0, 0.2
KITTI = CameraConfig()


@pytest.fixture(scope="module")
def mosaic() -> np.ndarray:
    return textured_mosaic(7, 1500, RES)


def _poses(n: int, seed: int = 0) -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(seed)
    return [(WEST + rng.uniform(100, 200), NORTH - rng.uniform(100, 200), rng.uniform(-3, 3)) for _ in range(n)]


def _camera(pitch: float) -> GroundCamera:
    return GroundCamera.from_config(dataclasses.replace(KITTI, pitch_rad=pitch), 0.5)  # 621 x 188 px


@pytest.mark.parametrize("pitch", [-0.05, 0.0, 0.08, 0.15])
def test_horizon_row_of_rendered_frames(mosaic: np.ndarray, pitch: float) -> None:
    """The sky-ground boundary of a world frame lies where the pitch puts the horizon, less the renderer's
    80 m ground range (atan(1.65 / 80) = 1.2 deg below it)."""
    cam = _camera(pitch)
    renderer = GroundRenderer(mosaic, from_origin(WEST, NORTH, RES, RES), cam)
    check = HorizonCheck(cam)
    for pose in _poses(3):
        row = horizon_row(renderer.render(pose))
        assert row is not None
        assert abs(math.degrees(check.pitch_of_row(row) - pitch) + 1.18) < 0.3, (row, check.expected_row)
    assert horizon_row(np.full((188, 621, 3), 128, np.uint8)) is None  # nothing to see: no horizon
    noise = np.random.default_rng(0).integers(0, 255, (188, 621, 3), np.uint8)
    assert horizon_row(noise) is None


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_misconfigured_pitch_warns_rate_limited(mosaic: np.ndarray) -> None:
    tf = from_origin(WEST, NORTH, RES, RES)
    frames = [GroundRenderer(mosaic, tf, _camera(0.12)).render(p) for p in _poses(8)]  # the camera looks 6.9 deg down
    clock = FakeClock()
    right = HorizonCheck(_camera(0.12), clock=clock)
    wrong = HorizonCheck(_camera(0.0), clock=clock)  # the profile says level
    for i, img in enumerate(frames):
        clock.t = float(i)
        right.observe(img)
        wrong.observe(img)
    assert right.take_warnings() == [] and right.warnings == 0
    (w,) = wrong.take_warnings()
    assert w.samples == 5 and w.configured_pitch_rad == 0.0 and 5.0 < math.degrees(w.measured_pitch_rad) < 6.5
    assert w.expected_row_px == pytest.approx(86.43, abs=0.01) and w.horizon_row_px < w.expected_row_px - 30
    assert w.text == "camera pitch +5.7deg? profile +0.0" and len(w.text) <= 50
    for i, img in enumerate(frames[:3]):  # within the 60 s interval: quiet
        clock.t = 10.0 + i
        wrong.observe(img)
    assert wrong.take_warnings() == []
    clock.t = 70.0
    wrong.observe(frames[0])
    assert len(wrong.take_warnings()) == 1 and wrong.warnings == 2


def test_horizon_check_through_a_calibrated_lens(mosaic: np.ndarray) -> None:
    """Distorted frames, undistorted by the rectifier: the horizon agrees with the right pitch and flags a wrong one."""
    K = np.array([[360.0, 0.0, 310.0], [0.0, 360.0, 94.0], [0.0, 0.0, 1.0]])
    lens = LensCalibration(K, np.array([-0.25, 0.06, 0.0, 0.0, 0.0]), LensModel.PLUMB_BOB, 621, 188)
    Kp = pinhole_matrix(lens)
    rect = FrameRectifier(621, 188, Kp, lens)
    renderer = LensRenderer(mosaic, from_origin(WEST, NORTH, RES, RES), lens, 1.65, 0.06)
    right = HorizonCheck(GroundCamera(Kp, 621, 188, 1.65, 0.06), clock=FakeClock())
    wrong = HorizonCheck(GroundCamera(Kp, 621, 188, 1.65, -0.06), clock=FakeClock())
    for pose in _poses(6, seed=1):
        img = rect(renderer.render(pose))
        assert abs(math.degrees(right.observe(img) - 0.06) + 1.18) < 0.4
        wrong.observe(img)
    assert right.take_warnings() == [] and len(wrong.take_warnings()) == 1


def test_check_is_off_when_the_horizon_is_outside_the_frame() -> None:
    steep = _camera(0.6)  # the horizon is 120 px above the frame
    check = HorizonCheck(steep)
    assert not check.enabled and check.observe(np.zeros((188, 621, 3), np.uint8)) is None


def test_mount_from_marks_recovers_height_and_pitch() -> None:
    cam = GroundCamera(np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]), 640, 480, 0.85, 0.21)
    uv, front = cam.project(np.array([[2.0, 0.0], [4.0, 0.3], [8.0, -0.2]]))
    assert front.all()
    marks = [(float(v), d) for (_, v), d in zip(uv, (2.0, 4.0, 8.0))]
    h, p = mount_from_marks(GroundCamera(cam.K, 640, 480, 1.0, 0.0), marks)
    assert h == pytest.approx(0.85, abs=1e-6) and p == pytest.approx(0.21, abs=1e-6)
    noisy = [(v + dv, d) for (v, d), dv in zip(marks, (0.5, -0.5, 0.5))]  # half a pixel of reading error
    h, p = mount_from_marks(cam, noisy)
    assert abs(h - 0.85) < 0.03 and abs(math.degrees(p - 0.21)) < 0.3
    with pytest.raises(ConfigError, match="at least two marks"):
        mount_from_marks(cam, marks[:1])
