"""Camera sources: image folder (KITTI image_02 layout), OpenCV VideoCapture on a video file, world: rendering."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

from taco_mav.camera import sources as camera_mod
from taco_mav.camera.calibration import FrameRectifier, LensCalibration, LensModel, pinhole_matrix
from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.sources import ClockDomain, FolderSource, VideoSource, open_camera, register_camera_scheme
from taco_mav.config import CameraConfig
from taco_mav.datasets.synthetic.world_camera import WorldSource, register_world_camera
from taco_mav.errors import ConfigError
from taco_mav.geo import UtmProjector

CAM = GroundCamera.from_config(CameraConfig(), scale=0.25)


def _folder(tmp_path: Path, n: int = 5) -> Path:
    d = tmp_path / "image_02"
    (d / "data").mkdir(parents=True)
    lines = []
    for i in range(n):
        img = np.full((20, 30, 3), i * 40, np.uint8)
        img[..., 2] = 255  # red in BGR order on disk
        cv2.imwrite(str(d / "data" / f"{i:010d}.png"), img)
        lines.append(f"2011-09-26 13:02:{25 + i * 0.1:012.9f}")
    (d / "timestamps.txt").write_text("\n".join(lines) + "\n")
    return tmp_path


def test_folder_source_times_and_rgb(tmp_path: Path) -> None:
    src = open_camera(f"folder:{_folder(tmp_path)}@100.0", CAM)
    assert isinstance(src, FolderSource) and src.clock is ClockDomain.AUTOPILOT
    assert src.times == pytest.approx([100.0, 100.1, 100.2, 100.3, 100.4])
    t, img = src.frame_near(100.23, 0.05)
    assert t == pytest.approx(100.2) and img.shape == (20, 30, 3)
    assert img[0, 0, 0] == 255 and img[0, 0, 2] == 80  # RGB: red channel first; frame 2 grey level 80
    assert src.frame_near(101.0, 0.05) is None


def test_folder_source_bad(tmp_path: Path) -> None:
    with pytest.raises(ConfigError):
        FolderSource(tmp_path)


def test_video_source_file(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (32, 24))
    if not writer.isOpened():
        pytest.skip("OpenCV build cannot write MJPG")
    for i in range(20):
        writer.write(np.full((24, 32, 3), (0, 0, 10 * i), np.uint8))
    writer.release()
    src = open_camera(str(path), CAM)
    assert isinstance(src, VideoSource) and src.clock is ClockDomain.COMPANION
    t0 = time.monotonic()
    src.start()
    deadline = t0 + 5.0
    while src.grabbed < 20 and time.monotonic() < deadline:
        time.sleep(0.02)
    src.close()
    assert src.grabbed == 20
    elapsed_grab = time.monotonic() - t0
    assert elapsed_grab >= 0.3  # paced at the file's 50 fps: 20 frames take ~0.4 s
    got = src.frame_near(time.monotonic(), 10.0)
    assert got is not None and got[1].shape == (24, 32, 3)
    assert got[1][0, 0, 0] > 150  # the last frame is the reddest, RGB order


def _mjpg(path: Path, frames: int = 10, fps: float = 50.0) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (32, 24))
    if not writer.isOpened():
        pytest.skip("OpenCV build cannot write MJPG")
    for i in range(frames):
        writer.write(np.full((24, 32, 3), (0, 0, 20 * i), np.uint8))
    writer.release()
    return path


def _grabbed(path: Path) -> VideoSource:
    """A VideoSource of the MJPG file `path` that has grabbed its 10 frames (closed); skips where this OpenCV's
    FFmpeg backend decodes MJPEG itself (no undecoded frames to test)."""
    src = VideoSource(str(path))
    src.start()
    deadline = time.monotonic() + 5.0
    while src.grabbed < 10 and time.monotonic() < deadline:
        time.sleep(0.02)
    src.close()
    if not src.encoded:
        pytest.skip("this OpenCV's FFmpeg backend does not hand over MJPEG frames undecoded")
    return src


def test_mjpeg_video_is_decoded_only_when_asked(tmp_path: Path) -> None:
    """An MJPEG file is grabbed undecoded (JPEG bytes in the ring, as a USB camera's MJPEG stream) and only the
    frame asked for is decoded: the same picture as OpenCV decoding every frame (within JPEG decoders' rounding)."""
    path = _mjpg(tmp_path / "clip.avi")
    src = _grabbed(path)
    assert src.grabbed == 10 and all(f.ndim == 2 and f.shape[0] == 1 for _, f in src._frames)
    t_last = src._frames[-1][0]
    got = src.frame_near(t_last, 0.001)
    assert got is not None and got[0] == t_last and got[1].shape == (24, 32, 3)
    cap = cv2.VideoCapture(str(path))
    for _ in range(10):
        bgr = cap.read()[1]
    cap.release()
    assert np.abs(got[1].astype(int) - bgr[..., ::-1]).max() <= 16  # RGB order, the last (reddest) frame
    assert src.frame_near(t_last, 0.001) is got  # asked again (another consumer): decoded once


def test_corrupt_jpeg_from_the_camera_is_a_corrupt_frame() -> None:
    from taco_mav.camera.sources import FrameRejected, _to_rgb

    with pytest.raises(FrameRejected) as exc:
        _to_rgb(np.frombuffer(b"\xff\xd8\xff garbage", np.uint8)[np.newaxis])
    assert exc.value.reason == "corrupt_frame"


def test_jpeg_decodes_to_rgb_exactly_as_bgr_swapped() -> None:
    """An MJPEG frame decoded straight to RGB (`_to_rgb`) is the BGR decode's pixels in RGB order, bit for bit."""
    from taco_mav.camera.sources import _to_rgb

    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.integers(0, 255, (72, 128, 3), dtype=np.uint8), (0, 0), 1.5)
    ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    rgb = _to_rgb(jpeg.reshape(1, -1))
    bgr = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
    assert rgb.shape == (72, 128, 3) and rgb.dtype == np.uint8
    assert np.array_equal(rgb, bgr[..., ::-1])
    assert int(np.abs(rgb.astype(int) - img[..., ::-1]).max()) <= 40  # the picture encoded, within JPEG's loss


def test_grey_frames_are_the_jpeg_luma_and_cached_apart(tmp_path: Path) -> None:
    """`frame_near(..., grey=True)` of an MJPEG frame is its luma plane (OpenCV's grey decode), within JPEG's
    rounding of the RGB frame's `COLOR_RGB2GRAY`, and is kept beside the RGB frame (each decoded once)."""
    path = _mjpg(tmp_path / "clip.avi")
    src = _grabbed(path)
    t_last, jpeg = src._frames[-1]
    grey = src.frame_near(t_last, 0.001, grey=True)
    rgb = src.frame_near(t_last, 0.001)
    assert grey is not None and rgb is not None and grey[1].shape == (24, 32) and rgb[1].shape == (24, 32, 3)
    assert np.array_equal(grey[1], cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE))
    assert np.abs(grey[1].astype(int) - cv2.cvtColor(rgb[1], cv2.COLOR_RGB2GRAY)).max() <= 2
    assert src.frame_near(t_last, 0.001, grey=True) is grey and src.frame_near(t_last, 0.001) is rgb


def test_video_source_unopenable() -> None:
    with pytest.raises(ConfigError):
        VideoSource("/nonexistent/clip.avi").start()


def _world(tmp_path: Path) -> None:
    """A textured 200 m square GeoTIFF about 49.0 N 8.4 E and the world.json naming it, in tmp_path."""
    proj = UtmProjector.for_latlon(49.0, 8.4)
    e0, n0 = proj.to_utm(49.0, 8.4)
    rng = np.random.default_rng(0)
    size, res = 800, 0.25
    tex = cv2.resize(rng.integers(0, 255, (100, 100, 3), dtype=np.uint8), (size, size), interpolation=cv2.INTER_NEAREST)
    tf = Affine(res, 0.0, e0 - size * res / 2, 0.0, -res, n0 + size * res / 2)
    with rasterio.open(tmp_path / "map.tif", "w", driver="GTiff", width=size, height=size, count=3, dtype="uint8",
                       crs=f"EPSG:{proj.epsg}", transform=tf) as ds:
        ds.write(np.transpose(tex, (2, 0, 1)))
    (tmp_path / "world.json").write_text(json.dumps({"mosaic": "map.tif"}))


def test_world_source_renders_at_pose(tmp_path: Path) -> None:
    _world(tmp_path)
    src = open_camera(f"world:{tmp_path}", CAM)
    assert src.frame_size() == (CAM.width, CAM.height)
    assert isinstance(src, WorldSource) and src.needs_pose and src.mosaic_path == (tmp_path / "map.tif").resolve()
    assert src.frame_near(1.0, 0.1) is None
    src.feed_pose(10.0, 49.0, 8.4, 0.0)
    src.feed_pose(10.1, 49.0, 8.4, math.pi / 2)
    t, north = src.frame_near(10.02, 0.05)
    assert t == 10.0 and north.shape == (CAM.height, CAM.width, 3)
    t2, east = src.frame_near(10.09, 0.05)
    assert t2 == 10.1 and np.abs(north.astype(int) - east.astype(int)).mean() > 10  # different view
    src.feed_pose(2.0, 49.0, 8.4, 0.0)  # clock went back (reboot): history cleared
    assert src.frame_near(10.0, 0.05) is None


def test_world_scheme_unregistered_is_one_line_error_then_registered_opens(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """camera/sources.py knows no world renderer: `world:` works only once datasets.synthetic registered it."""
    _world(tmp_path)
    monkeypatch.setattr(camera_mod, "_SCHEMES", {})  # as if taco_mav.datasets.synthetic were never imported
    with pytest.raises(ConfigError) as err:
        open_camera(f"world:{tmp_path}", CAM)
    msg = str(err.value)
    assert "\n" not in msg and f"world:{tmp_path}" in msg and "not registered" in msg
    assert "taco_mav.datasets.synthetic" in msg
    register_world_camera()
    register_world_camera()  # idempotent
    assert camera_mod.camera_schemes() == ("world",)
    src = open_camera(f"world:{tmp_path}", CAM)
    assert isinstance(src, WorldSource) and src.mosaic_path == (tmp_path / "map.tif").resolve()
    assert src.needs_pose and src.noiseless and src.clock is ClockDomain.AUTOPILOT


def test_unknown_camera_scheme_is_one_line_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ConfigError, match=r"--camera 'wrld:/x': unknown camera scheme 'wrld:' \(known: folder:"):
        open_camera("wrld:/x", CAM)
    # URLs, pipelines and files whose names hold a colon are not schemes: they go to OpenCV
    for spec in ("rtsp://cam.local/stream", "udpsrc port=5000 caps=application/x-rtp ! decodebin ! appsink"):
        assert isinstance(open_camera(spec, CAM), VideoSource)
    odd = tmp_path / "clip:1.avi"
    odd.write_bytes(b"")
    assert isinstance(open_camera(str(odd), CAM), VideoSource)
    # a registered scheme gets the body, the camera model and the lens
    monkeypatch.setattr(camera_mod, "_SCHEMES", {})
    seen: list[tuple] = []
    register_camera_scheme("fake", lambda body, cam, lens: seen.append((body, cam, lens)) or "src")
    assert open_camera("fake:a:b@1", CAM) == "src" and seen == [("a:b@1", CAM, None)]
    assert camera_mod.unregister_camera_scheme("fake") is not None and camera_mod.camera_schemes() == ()
    with pytest.raises(ValueError):
        register_camera_scheme("folder", lambda body, cam, lens: None)


def test_real_sources_have_no_mosaic(tmp_path: Path) -> None:
    assert open_camera(f"folder:{_folder(tmp_path)}", CAM).mosaic_path is None
    assert VideoSource("0").mosaic_path is None


def test_world_source_renders_through_a_lens(tmp_path: Path) -> None:
    """world: with the profile's calibration: frames of the lens's size, distorted; the rectifier undoes it."""
    _world(tmp_path)
    D = np.array([-0.3, 0.1, 0.0, 0.0, 0.0])
    lens = LensCalibration(CAM.K.copy(), D, LensModel.PLUMB_BOB, CAM.width, CAM.height)
    src = open_camera(f"world:{tmp_path}", GroundCamera(pinhole_matrix(lens), CAM.width, CAM.height, 1.65), lens)
    assert src.frame_size() == (CAM.width, CAM.height)
    plain = open_camera(f"world:{tmp_path}", GroundCamera(pinhole_matrix(lens), CAM.width, CAM.height, 1.65))
    for s in (src, plain):
        s.feed_pose(10.0, 49.0, 8.4, 0.3)
    _, raw = src.frame_near(10.0, 0.1)
    _, pin = plain.frame_near(10.0, 0.1)
    rect = FrameRectifier(CAM.width, CAM.height, pinhole_matrix(lens), lens)
    ground = slice(CAM.height // 2 + 5, CAM.height)
    d_rect = np.abs(rect(raw).astype(float) - pin)[ground].mean()
    d_raw = np.abs(raw.astype(float) - pin)[ground].mean()
    assert raw.shape == pin.shape == (CAM.height, CAM.width, 3) and d_raw > 3 * d_rect, (d_raw, d_rect)


def test_sources_tell_their_frame_size(tmp_path: Path) -> None:
    assert open_camera(f"folder:{_folder(tmp_path)}", CAM).frame_size() == (30, 20)
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (32, 24))
    if not writer.isOpened():
        pytest.skip("OpenCV build cannot write MJPG")
    for i in range(3):
        writer.write(np.full((24, 32, 3), 10 * i, np.uint8))
    writer.release()
    video = open_camera(str(path), CAM)
    assert video.frame_size() is None  # not opened yet
    video.start()
    assert video.frame_size() == (32, 24)
    video.close()
