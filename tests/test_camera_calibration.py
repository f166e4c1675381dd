"""Lens calibration files (OpenCV FileStorage, ROS camera_info), the profile's camera.calibration, frame
rectification (undistortion and scaling), rendering through a lens, and the whole path distorted world frame ->
undistort -> IPM -> classical matcher against the pinhole case and the uncalibrated one."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from rasterio.transform import from_origin

from taco_mav.bench.classical import textured_mosaic, write_geotiff
from taco_mav.camera.calibration import (FrameRectifier, LensCalibration, LensModel, load_calibration, pinhole_matrix,
                                         scale_matrix, write_calibration)
from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.sources import FrameGuard, FrameRejected
from taco_mav.config import CameraConfig, ClassicalMatcherConfig, load_profile, profile_from_dict, profile_to_dict
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.classical import ClassicalMatcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.datasets.synthetic.render import GroundRenderer, LensRenderer
from taco_mav.errors import ConfigError

KITTI = CameraConfig()
K_KITTI = np.array([[KITTI.fx, 0.0, KITTI.cx], [0.0, KITTI.fy, KITTI.cy], [0.0, 0.0, 1.0]])
BARREL = LensCalibration(K_KITTI, np.array([-0.3, 0.1, 0.0, 0.0, 0.0]), LensModel.PLUMB_BOB, 1242, 375)
FISHEYE = LensCalibration(np.array([[300.0, 0.0, 321.0], [0.0, 300.0, 238.0], [0.0, 0.0, 1.0]]),
                          np.array([0.06, -0.02, 0.004, 0.0]), LensModel.FISHEYE, 640, 480)

ROS_YAML = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [300.0, 0.0, 321.0, 0.0, 300.0, 238.0, 0.0, 0.0, 1.0]
distortion_model: {model}
distortion_coefficients:
  rows: 1
  cols: {n}
  data: [{coeffs}]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [300.0, 0.0, 321.0, 0.0, 0.0, 300.0, 238.0, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


def _ros(path: Path, model: str = "plumb_bob", coeffs: str = "-0.2, 0.05, 0.001, -0.001, 0.0") -> Path:
    path.write_text(ROS_YAML.format(model=model, n=len(coeffs.split(",")), coeffs=coeffs))
    return path


def test_reads_opencv_filestorage_as_opencv_writes_it(tmp_path: Path) -> None:
    fs = cv2.FileStorage(str(tmp_path / "cv.yaml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1242)
    fs.write("image_height", 375)
    fs.write("camera_matrix", K_KITTI)
    fs.write("distortion_coefficients", np.array([[-0.3], [0.1], [0.0], [0.0], [0.0]]))
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    lens = load_calibration(tmp_path / "cv.yaml")
    assert lens.model is LensModel.PLUMB_BOB and (lens.width, lens.height) == (1242, 375)
    np.testing.assert_allclose(lens.K, K_KITTI)
    np.testing.assert_allclose(lens.D, [-0.3, 0.1, 0.0, 0.0, 0.0])
    write_calibration(tmp_path / "ours.yaml", FISHEYE, {"avg_reprojection_error": 0.1})
    back = load_calibration(tmp_path / "ours.yaml")
    assert back.model is LensModel.FISHEYE and (back.width, back.height) == (640, 480)
    np.testing.assert_allclose(back.D, FISHEYE.D)


@pytest.mark.parametrize("model, coeffs, expect", [("plumb_bob", "-0.2, 0.05, 0.001, -0.001, 0.0", LensModel.PLUMB_BOB),
                                                   ("equidistant", "0.06, -0.02, 0.004, 0.0", LensModel.FISHEYE),
                                                   ("fisheye", "0.06, -0.02, 0.004, 0.0", LensModel.FISHEYE)])
def test_reads_ros_camera_info(tmp_path: Path, model: str, coeffs: str, expect: LensModel) -> None:
    lens = load_calibration(_ros(tmp_path / "ros.yaml", model, coeffs))
    assert lens.model is expect and (lens.width, lens.height) == (640, 480)
    assert lens.K[0, 0] == 300.0 and lens.K[1, 2] == 238.0 and lens.D[0] == float(coeffs.split(",")[0])


@pytest.mark.parametrize("edit, needle", [
    (("camera_matrix:\n  rows: 3\n  cols: 3\n  data: [300.0, 0.0, 321.0, 0.0, 300.0, 238.0, 0.0, 0.0, 1.0]\n", ""),
     "key camera_matrix missing"),
    (("data: [300.0, 0.0, 321.0, 0.0, 300.0, 238.0, 0.0, 0.0, 1.0]", "data: [300.0, 0.0, 321.0, 0.0, 300.0, 238.0]"),
     "key camera_matrix: 'data' must be 3x3 numbers"),
    (("data: [300.0, 0.0, 321.0, 0.0, 300.0, 238.0, 0.0, 0.0, 1.0]", "data: [-300.0, 0, 321, 0, 300, 238, 0, 0, 1]"),
     "key camera_matrix: expected [[fx"),
    (("image_width: 640", "image_width: wide"), "key image_width: expected a positive integer"),
    (("distortion_model: plumb_bob", "distortion_model: mei"), "key distortion_model: 'mei' is not one of"),
    (("distortion_model: plumb_bob", "distortion_model: equidistant"),
     "key distortion_coefficients: fisheye takes 4 finite numbers, got 5"),
    (("image_width: 640", "image_width: [640"), "not valid YAML (line 2)"),
])
def test_bad_calibration_files_name_file_and_key(tmp_path: Path, edit: tuple[str, str], needle: str) -> None:
    path = _ros(tmp_path / "cam.yaml")
    path.write_text(path.read_text().replace(*edit))
    with pytest.raises(ConfigError) as exc:
        load_calibration(path)
    assert str(path) in str(exc.value) and needle in str(exc.value), str(exc.value)


def test_profile_calibration_resolves_against_the_profile_folder(tmp_path: Path) -> None:
    (tmp_path / "cal").mkdir()
    write_calibration(tmp_path / "cal" / "front.yaml", BARREL)
    prof = tmp_path / "rover.yaml"
    prof.write_text("camera:\n  calibration: cal/front.yaml\n  mount_height_m: 0.5\n  pitch_rad: 0.1\n")
    cam = load_profile(prof).camera
    Kp = pinhole_matrix(BARREL)
    assert cam.calibration == str((tmp_path / "cal" / "front.yaml").resolve())
    assert (cam.width_px, cam.height_px, cam.mount_height_m, cam.pitch_rad) == (1242, 375, 0.5, 0.1)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((Kp[0, 0], Kp[1, 1], Kp[0, 2], Kp[1, 2]))
    # barrel distortion: the all-valid undistorted view needs a slightly shorter focal length (706 vs 721.5 px)
    assert 700.0 < cam.fx < KITTI.fx
    g = GroundCamera.from_config(cam)
    np.testing.assert_allclose(g.K, Kp)
    # a processing size of the same aspect: the model scales; the resolved profile loads again unchanged
    half = profile_from_dict({"camera": {"calibration": str(tmp_path / "cal" / "front.yaml"), "width_px": 621,
                                         "height_px": 188}}).camera
    assert (half.fx, half.cx) == pytest.approx((Kp[0, 0] / 2, (Kp[0, 2] + 0.5) / 2 - 0.5))
    again = profile_from_dict(profile_to_dict(profile_from_dict({"camera": {"calibration": cam.calibration}})))
    assert again.camera == profile_from_dict({"camera": {"calibration": cam.calibration}}).camera


@pytest.mark.parametrize("camera, needle", [
    ({"calibration": "nope.yaml"}, "camera.calibration: {dir}/nope.yaml not found"),
    ({"calibration": "front.yaml", "fx": 700.0}, "camera.fx: 700.0 disagrees with the calibration"),
    ({"calibration": "front.yaml", "width_px": 640, "height_px": 480},
     "camera.width_px: 640x480 px has another aspect ratio than the calibration {dir}/front.yaml (1242x375 px)"),
    ({"calibration": "front.yaml", "width_px": 621}, "camera.width_px: give both width_px and height_px"),
    ({"calibration": "broken.yaml"}, "camera.calibration: {dir}/broken.yaml: key image_height missing"),
])
def test_bad_profile_calibration_names_file_and_key(tmp_path: Path, camera: dict, needle: str) -> None:
    write_calibration(tmp_path / "front.yaml", BARREL)
    (tmp_path / "broken.yaml").write_text("image_width: 10\ncamera_matrix: [1, 0, 5, 0, 1, 5, 0, 0, 1]\n")
    prof = tmp_path / "p.yaml"
    prof.write_text(yaml.safe_dump({"camera": camera}))
    with pytest.raises(ConfigError) as exc:
        load_profile(prof)
    text = str(exc.value)
    assert text.startswith(f"{prof}:") and needle.format(dir=tmp_path.resolve()) in text, text


def _dots(lens: LensCalibration, xy: np.ndarray) -> np.ndarray:
    """A grey raw frame with a Gaussian dot (sigma 1.5 px) where each normalised point (x, y) is imaged."""
    img = np.zeros((lens.height, lens.width), np.float32)
    u, v = np.meshgrid(np.arange(lens.width), np.arange(lens.height))
    for px, py in lens.distort(xy):
        img += 200.0 * np.exp(-((u - px) ** 2 + (v - py) ** 2) / (2 * 1.5**2))
    return np.clip(img, 0, 255).astype(np.uint8)


def _centroids(img: np.ndarray, near: np.ndarray, r: int = 6) -> np.ndarray:
    out = []
    for px, py in near:
        x0, y0 = int(round(px)) - r, int(round(py)) - r
        patch = img[y0:y0 + 2 * r + 1, x0:x0 + 2 * r + 1].astype(float)
        yy, xx = np.mgrid[y0:y0 + 2 * r + 1, x0:x0 + 2 * r + 1]
        out.append(((xx * patch).sum() / patch.sum(), (yy * patch).sum() / patch.sum()))
    return np.array(out)


@pytest.mark.parametrize("lens", [BARREL, FISHEYE], ids=["plumb_bob", "fisheye"])
@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_rectified_dots_land_where_the_pinhole_model_puts_them(lens: LensCalibration, scale: float) -> None:
    """Points imaged through the lens (cv2.projectPoints / fisheye.distortPoints) come out of the rectifier at
    K_model (x, y, 1), also from frames of half the calibrated size."""
    Kp = pinhole_matrix(lens)
    rect = FrameRectifier(lens.width, lens.height, Kp, lens)
    gu, gv = np.meshgrid(np.linspace(20.0, lens.width - 21.0, 7), np.linspace(15.0, lens.height - 16.0, 4))
    xy = (np.c_[gu.ravel(), gv.ravel(), np.ones(gu.size)] @ np.linalg.inv(Kp).T)[:, :2]  # over the model's view
    raw_lens = lens.scaled(round(lens.width * scale), round(lens.height * scale)) if scale != 1.0 else lens
    out = rect(_dots(raw_lens, xy))
    assert out.shape == (lens.height, lens.width)
    expect = np.c_[xy, np.ones(len(xy))] @ Kp.T
    got = _centroids(out, expect[:, :2])
    err = np.hypot(*(got - expect[:, :2]).T)
    assert err.max() < (0.15 if scale == 1.0 else 0.35), err.round(3)
    # and the raw dots are far from there: the lens matters
    assert np.hypot(*(lens.distort(xy) - expect[:, :2]).T).max() > 10.0


def test_rectifier_refuses_another_aspect_and_guard_scales_frames() -> None:
    rect = FrameRectifier.from_config(CameraConfig(width_px=160, height_px=120, fx=100.0, fy=100.0, cx=79.5, cy=59.5))
    with pytest.raises(ConfigError, match=r"^cam: frames are 100x60 px but the profile camera.width_px x height_px "
                                          r"is 160x120 px: another aspect ratio \(1.667 vs 1.333\)"):
        rect.check_size(100, 60, "cam")
    rect.check_size(320, 240)
    img = np.random.default_rng(0).integers(0, 255, (60, 80, 3), np.uint8)
    guard = FrameGuard(160, 120, 0.1, rectifier=rect)
    t, out = guard.check((1.0, img), 1.0)
    assert out.shape == (120, 160, 3) and abs(float(out.mean()) - float(img.mean())) < 2.0
    with pytest.raises(FrameRejected) as exc:
        guard.check((2.0, img[:, :70]), 2.0)
    assert exc.value.reason == "bad_shape" and "or the same aspect" in exc.value.detail
    assert rect(np.zeros((120, 160, 3), np.uint8)).shape == (120, 160, 3)  # the model size passes unchanged
    np.testing.assert_allclose(scale_matrix(np.eye(3), (160, 120), (80, 60)),
                               [[0.5, 0, -0.25], [0, 0.5, -0.25], [0, 0, 1]])


# ------------------------------------------------------------------------------------- the whole path
WEST, NORTH, RES, SIZE = 500_000.0, 5_430_000.0, 0.2, 1500


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory):
    folder = Path(tmp_path_factory.mktemp("lens"))
    mosaic = textured_mosaic(7, SIZE, RES)
    write_geotiff(folder / "mosaic.tif", mosaic, WEST, NORTH, RES)
    write_calibration(folder / "front.yaml", BARREL)
    cam_cfg = profile_from_dict({"camera": {"calibration": str(folder / "front.yaml")}}).camera
    (folder / "world.json").write_text('{"mosaic": "mosaic.tif"}')
    smap = SatelliteMap(folder / "mosaic.tif")
    yield mosaic, from_origin(WEST, NORTH, RES, RES), cam_cfg, smap
    smap.close()


def test_lens_render_undistorts_to_the_pinhole_render(world) -> None:
    mosaic, tf, cam_cfg, _ = world
    model = GroundCamera.from_config(cam_cfg)
    pose = (WEST + 150.0, NORTH - 140.0, math.radians(63.0))
    raw = LensRenderer(mosaic, tf, BARREL, model.mount_height_m, model.pitch_rad).render(pose)
    assert raw.shape == (375, 1242, 3)
    pin = GroundRenderer(mosaic, tf, model).render(pose).astype(float)
    rect = FrameRectifier.from_config(cam_cfg)
    ground = slice(200, 375)  # rows of textured ground near the vehicle
    diff_rect = np.abs(rect(raw).astype(float) - pin)[ground].mean()
    diff_raw = np.abs(raw.astype(float) - pin)[ground].mean()
    assert diff_rect < 4.0 and diff_raw > 4 * diff_rect, (diff_rect, diff_raw)


def test_classical_matcher_on_distorted_frames(world) -> None:
    """Distorted world frames: undistorted with the calibration the classical matcher is as accurate as on
    pinhole frames; the same frames taken as pinhole (no calibration) are clearly worse."""
    mosaic, tf, cam_cfg, smap = world
    model = GroundCamera.from_config(cam_cfg)
    uncal = GroundCamera.from_config(KITTI)  # the lens's K, distortion ignored
    rect = FrameRectifier.from_config(cam_cfg)
    pin = GroundRenderer(mosaic, tf, model, max_range_m=80.0)
    lensr = LensRenderer(mosaic, tf, BARREL, model.mount_height_m, model.pitch_rad, max_range_m=80.0)
    half = LensRenderer(mosaic, tf, BARREL.scaled(621, 188), model.mount_height_m, model.pitch_rad, max_range_m=80.0)
    m_model = ClassicalMatcher(ClassicalMatcherConfig(), model)
    m_uncal = ClassicalMatcher(ClassicalMatcherConfig(), uncal)
    rng = np.random.default_rng(3)
    errors: dict[str, list[float]] = {"pinhole": [], "calibrated": [], "calibrated_half_size": [], "uncalibrated": []}
    for _ in range(12):
        e, n, th = WEST + rng.uniform(120, 180), NORTH - rng.uniform(120, 180), rng.uniform(-math.pi, math.pi)
        fwd, left, psi = rng.uniform(-6, 6), rng.uniform(-6, 6), math.radians(rng.uniform(-6, 6))
        q = th - psi
        c, s = math.cos(q), math.sin(q)
        centre = np.array([e, n]) - fwd * np.array([c, s]) - left * np.array([-s, c])
        crop = smap.crop(centre, q, 512, 0.2)
        raw = lensr.render((e, n, th))
        for name, img, matcher, cam in (("pinhole", pin.render((e, n, th)), m_model, model),
                                        ("calibrated", rect(raw), m_model, model),
                                        ("calibrated_half_size", rect(half.render((e, n, th))), m_model, model),
                                        ("uncalibrated", raw, m_uncal, uncal)):
            (r,) = matcher.match(GroundFrame(img, 0.0, cam), [crop])
            errors[name].append(float(np.hypot(*(r.t - [fwd, left]))))
    med = {k: float(np.median(v)) for k, v in errors.items()}
    print("median position error, m:", {k: round(v, 3) for k, v in med.items()})
    assert med["pinhole"] < 0.35
    assert med["calibrated"] < med["pinhole"] + 0.1 and med["calibrated_half_size"] < med["pinhole"] + 0.15
    assert med["uncalibrated"] > 0.5 and med["uncalibrated"] > 2.5 * med["calibrated"]


def test_fix_pipeline_undistorts_a_calibrated_world_camera(world) -> None:
    """The daemon's wiring: profile camera.calibration -> world camera drawn through the lens (raw 1242 x 375
    distorted frames) -> frame guard undistorts -> GroundFrame of the pinhole model -> the profile's classical
    matcher finds the true offset."""
    from fault_helpers import Counters

    from taco_mav.core.types import FixQuery
    from taco_mav.daemon.daemon import DaemonOptions
    from taco_mav.daemon.eventlog import EventLog
    from taco_mav.daemon.fixes import FixPipeline
    from taco_mav.geo import UtmProjector
    from taco_mav.mavlink.decoders import SimPose
    from taco_mav.mavlink.timesync import ClockMap

    _, _, cam_cfg, smap = world
    folder = Path(cam_cfg.calibration).parent
    profile = profile_from_dict({"matcher": "classical", "camera": {"calibration": cam_cfg.calibration}})
    pipe = FixPipeline(profile=profile, options=DaemonOptions(connect="udpin:127.0.0.1:1", camera=f"world:{folder}"),
                       clockmap=ClockMap(), stats=Counters(), status=lambda sev, text, key: None)
    pipe.open(EventLog(None))
    pipe.start()
    try:
        assert pipe.camera.frame_size() == (1242, 375)
        proj = UtmProjector(32632)
        e, n = WEST + 160.0, NORTH - 150.0
        lat, lon = proj.to_latlon(e, n)
        yaw = 0.4
        pipe.on_pose(5.0, SimPose(lat, lon, yaw))
        theta = math.pi / 2 - yaw + float(proj.grid_convergence(lat, lon))
        q = FixQuery(1, 5.0, np.zeros(2), theta, np.zeros((1, 2)), np.zeros((1, 2)), 1.0)
        frame = pipe._frame_fetcher(q)()
        assert frame.image.shape == (375, 1242, 3) and frame.camera is pipe.ground_camera
        np.testing.assert_allclose(frame.camera.K, pinhole_matrix(BARREL))
        c, s_ = math.cos(theta), math.sin(theta)
        crop = smap.crop(np.array([e, n]) - 4.0 * np.array([c, s_]) - 3.0 * np.array([-s_, c]), theta, 512, 0.2)
        (r,) = pipe.matcher.match(frame, [crop])
        assert np.hypot(*(r.t - [4.0, 3.0])) < 0.6, r.t
    finally:
        pipe.stop()
        pipe.close()
