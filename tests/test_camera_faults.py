"""Camera and map faults: the frame guard's verdicts on real images and files; the fix pipeline (real worker
thread, real Localiser, real PNG folders and a real GeoTIFF) skipping and counting bad frames and off-map
crops while the uncertainty grows honestly; the daemon over loopback degrading its fix type when the camera
freezes."""

from __future__ import annotations

import dataclasses
import math
import re
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fault_helpers import (ORIGIN_LAT, ORIGIN_LON, noise_image, run_pipeline, small_camera_profile, straight_drive,
                           write_folder, write_geotiff)
from mav_autopilot import MiniAutopilot, free_udp_port

from taco_mav.camera.sources import FolderSource, FrameGuard, FrameRejected, FreezeWatch, VideoSource
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.errors import ConfigError
from taco_mav.geo import UtmProjector
from taco_mav.mavlink.encoders import Origin

DRIVE_S = 12.0


def _reason(guard: FrameGuard, got: object, t: float) -> str:
    try:
        guard.check(got, t)  # type: ignore[arg-type]
    except FrameRejected as exc:
        return exc.reason
    return "ok"


def test_guard_verdicts() -> None:
    g = FrameGuard(160, 120, max_gap_s=0.15)
    img = noise_image(1)
    assert _reason(g, None, 5.0) == "no_frame"
    assert _reason(g, (6.0, img), 5.0) == "stale_frame"
    assert _reason(g, (float("nan"), img), 5.0) == "stale_frame"
    assert _reason(g, (5.0, noise_image(1, 80, 60)), 5.0) == "bad_shape"
    assert _reason(g, (5.0, img[..., 0]), 5.0) == "bad_shape"  # grey
    assert _reason(g, (5.0, img.astype(np.float32)), 5.0) == "bad_shape"
    assert _reason(g, (5.0, np.zeros_like(img)), 5.0) == "blank_frame"  # lens cap
    assert _reason(g, (5.0, np.full_like(img, 255)), 5.0) == "blank_frame"  # saturated
    assert _reason(g, (5.0, img), 5.0) == "ok"
    assert _reason(g, (5.0, img), 5.05) == "ok"  # the same frame asked for twice is not frozen
    assert _reason(g, (5.1, img.copy()), 5.1) == "frozen_frame"  # same pixels, another time
    assert _reason(g, (5.2, img.copy()), 5.2) == "frozen_frame"
    assert _reason(g, (5.3, noise_image(2)), 5.3) == "ok"  # the camera lives again
    quiet = FrameGuard(160, 120, 0.15, check_frozen=False)  # a renderer (world:) repeats itself legitimately
    assert _reason(quiet, (1.0, img), 1.0) == "ok" and _reason(quiet, (1.1, img), 1.1) == "ok"



def test_a_freeze_one_consumer_sees_is_refused_by_the_other() -> None:
    """The matcher, one frame every few seconds, never sees a picture twice, so a hung camera's picture, a second
    old and stamped now, passes its own guard and would be a fix 3 m behind the rover (SITL, docs/sitl.md). The
    camera-speed loop's guard (grey, every 0.5 s) sees the repeat; through the shared FreezeWatch the matcher's
    guard refuses frames stamped after the freeze began until that loop sees the picture change."""
    watch = FreezeWatch()
    fix = FrameGuard(160, 120, max_gap_s=0.15, freeze=watch)
    speed = FrameGuard(160, 120, max_gap_s=0.15, grey=True, freeze=watch)
    alone = FrameGuard(160, 120, max_gap_s=0.15)  # a guard without the shared watch
    hung = noise_image(2)
    assert _reason(fix, (5.0, noise_image(1)), 5.0) == "ok" and _reason(alone, (5.0, noise_image(1)), 5.0) == "ok"
    assert _reason(speed, (5.5, np.ascontiguousarray(hung[..., 0])), 5.5) == "ok"
    assert watch.frozen_since() is None
    assert _reason(speed, (6.0, np.ascontiguousarray(hung[..., 0])), 6.0) == "frozen_frame"
    assert watch.frozen_since() == 5.5
    assert _reason(alone, (6.5, hung.copy()), 6.5) == "ok"  # the defect: new to this guard, so it passed
    with pytest.raises(FrameRejected, match="not changed since 5.500 s"):
        fix.check((6.5, hung.copy()), 6.5)
    assert _reason(fix, (5.4, noise_image(3)), 5.4) == "ok"  # a frame from before the freeze is still good
    assert _reason(speed, (7.0, np.ascontiguousarray(noise_image(4)[..., 0])), 7.0) == "ok"  # it lives again
    assert watch.frozen_since() is None
    assert _reason(fix, (7.0, noise_image(4)), 7.0) == "ok"

@pytest.mark.parametrize("step, verdict", [(3, "blank_frame"), (5, "ok")])
def test_guard_blank_is_the_std_of_every_4th_pixel(step: int, verdict: str) -> None:
    """Blank means a grey-level std under min_std (2) over every 4th pixel of every 4th row, all channels: half
    of those pixels 100 and half 100 + step is a std of step / 2 (1.5: blank; 2.5: not), whatever lies between."""
    img = np.full((120, 160, 3), 100, np.uint8)
    img[1::4, 1::4] = 250  # off the subsample: never seen
    img[::8, ::4] = 100 + step  # every other subsampled row
    assert _reason(FrameGuard(160, 120, max_gap_s=0.15), (5.0, img), 5.0) == verdict


def test_grey_guard_takes_grey_frames_only() -> None:
    """A grey guard (camera speed) passes grey (H, W) frames and vets them as the RGB one does; RGB is a bad shape."""
    g = FrameGuard(160, 120, max_gap_s=0.15, grey=True)
    img = noise_image(1)
    grey = np.ascontiguousarray(img[..., 0])
    assert _reason(g, (5.0, grey), 5.0) == "ok"
    assert _reason(g, (5.0, img), 5.0) == "bad_shape"
    assert _reason(g, (5.0, np.zeros_like(grey)), 5.0) == "blank_frame"
    assert _reason(g, (5.1, grey.copy()), 5.1) == "frozen_frame"
    t, out = g.check((5.2, np.ascontiguousarray(noise_image(2)[..., 1])), 5.2)
    assert t == 5.2 and out.shape == (120, 160) and out.dtype == np.uint8


def test_folder_grey_is_the_rgb_frame_in_grey(tmp_path: Path) -> None:
    src = FolderSource(write_folder(tmp_path / "a", [noise_image(0), noise_image(1)]))
    t, rgb = src.frame_near(0.0, 0.05)
    tg, grey = src.frame_near(0.0, 0.05, grey=True)
    assert t == tg and grey.shape == (120, 160)
    assert np.array_equal(grey, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


def test_folder_corrupt_and_empty(tmp_path: Path) -> None:
    src = FolderSource(write_folder(tmp_path / "a", [noise_image(0), b"\x89PNG garbage" * 50, noise_image(2)]))
    assert src.frame_near(0.0, 0.05)[1].shape == (120, 160, 3)
    with pytest.raises(FrameRejected) as exc:
        src.frame_near(0.1, 0.05)
    assert exc.value.reason == "corrupt_frame"


def test_live_camera_without_frames_is_no_frame(tmp_path: Path) -> None:
    """A video source that has grabbed nothing (unplugged camera) gives no frame: rejected as no_frame."""
    cam = VideoSource(str(tmp_path / "never-opened.mp4"))
    guard = FrameGuard(160, 120, 0.15)
    assert _reason(guard, cam.frame_near(time.monotonic(), 60.0), time.monotonic()) == "no_frame"


def _frames(kind: str) -> list[np.ndarray | bytes]:
    n = int(DRIVE_S * 10) + 5
    if kind == "good":
        return [noise_image(i) for i in range(n)]
    if kind == "corrupt_frame":
        return [np.random.default_rng(i).bytes(3000) for i in range(n)]
    if kind == "blank_frame":
        return [np.zeros((120, 160, 3), np.uint8)] * n
    if kind == "bad_shape":  # the camera switched to another aspect after its first frame (checked at start-up)
        return [noise_image(0)] + [noise_image(i, 100, 60) for i in range(1, n)]
    if kind == "frozen_frame":
        return [noise_image(7)] * n
    assert kind == "stale_frame"
    return [noise_image(i) for i in range(10)]  # the camera died after 1 s


@pytest.mark.parametrize("kind", ["corrupt_frame", "blank_frame", "bad_shape", "frozen_frame", "stale_frame"])
def test_bad_frames_skipped_counted_and_sigma_grows(kind: str, tmp_path: Path) -> None:
    drive = straight_drive(DRIVE_S)
    run = run_pipeline(small_camera_profile(), drive, camera=f"folder:{write_folder(tmp_path, _frames(kind))}")
    fixes = run.stats.fixes
    accepted = fixes.get("accepted", 0)
    assert accepted == (1 if kind == "frozen_frame" else 0), fixes  # a frozen camera's first frame is new
    assert fixes[kind] == run.stats.queries - accepted >= 4, fixes  # every other trigger skipped for its reason
    assert set(fixes) <= {kind, "accepted"}
    assert any(t == f"no fix: {kind}" for t in run.texts)
    # honest: no fix, so the 1-sigma keeps growing past the degrade threshold (10 m), covering the error
    late = run.t > run.t[-1] - 4.0
    assert np.all(np.diff(run.sigma[late]) > 0) and run.sigma[-1] > 10.0
    assert np.all(run.errors <= 3.0 * run.sigma + 0.01)


def test_good_frames_control(tmp_path: Path) -> None:
    run = run_pipeline(small_camera_profile(), straight_drive(DRIVE_S),
                       camera=f"folder:{write_folder(tmp_path, _frames('good'))}")
    assert run.stats.fixes["accepted"] == run.stats.queries >= 4
    assert run.sigma[run.t > run.t[-1] - 4.0].min() < 5.0  # fixes every ~2 s keep it small


def test_frames_of_another_size_are_scaled(tmp_path: Path) -> None:
    """A camera streaming 80 x 60 px (the profile says 160 x 120): frames are scaled, every trigger answered."""
    run = run_pipeline(small_camera_profile(), straight_drive(DRIVE_S),
                       camera=f"folder:{write_folder(tmp_path, [noise_image(i, 80, 60) for i in range(125)])}")
    assert run.stats.fixes["accepted"] == run.stats.queries >= 4


def test_camera_of_another_aspect_is_refused_at_start(tmp_path: Path) -> None:
    folder = write_folder(tmp_path, [noise_image(i, 100, 60) for i in range(5)])
    with pytest.raises(ConfigError) as exc:
        run_pipeline(small_camera_profile(), straight_drive(2.0), camera=f"folder:{folder}")
    assert str(exc.value) == (f"--camera folder:{folder}: frames are 100x60 px but the profile camera.width_px x "
                              "height_px is 160x120 px: another aspect ratio (1.667 vs 1.333), cannot be scaled")


def test_misconfigured_pitch_warns_by_statustext(tmp_path: Path) -> None:
    """Frames of a camera looking 0.12 rad down, a profile saying level: one "camera pitch" STATUSTEXT."""
    from rasterio.transform import from_origin

    from taco_mav.bench.classical import textured_mosaic
    from taco_mav.camera.geometry import GroundCamera
    from taco_mav.datasets.synthetic.render import GroundRenderer

    profile = small_camera_profile()
    cam = GroundCamera.from_config(dataclasses.replace(profile.camera, pitch_rad=0.12))
    renderer = GroundRenderer(textured_mosaic(3, 1200, 0.2), from_origin(0.0, 240.0, 0.2, 0.2), cam)
    frames = [renderer.render((60.0 + 0.5 * i, 120.0, 0.0)) for i in range(125)]
    run = run_pipeline(profile, straight_drive(DRIVE_S), camera=f"folder:{write_folder(tmp_path, frames)}")
    assert run.stats.fixes["accepted"] == run.stats.queries >= 4
    warned = [t for t in run.texts if t.startswith("camera pitch")]
    assert len(warned) == 1 and re.fullmatch(r"camera pitch \+5\.\ddeg\? profile \+0\.0", warned[0]), run.texts


def test_drive_off_the_map(tmp_path: Path) -> None:
    """A 300 m square GeoTIFF; the drive goes 400 m east: crops off the map are counted, triggers without any
    crop on the map give no fix, the 1-sigma grows past 10 m, nothing crashes."""
    origin = Origin.from_latlon(ORIGIN_LAT, ORIGIN_LON, 100.0)
    tif = write_geotiff(tmp_path / "map.tif", origin, half_m=150.0)
    drive = straight_drive(40.0, speed=10.0, theta0=0.0)
    run = run_pipeline(small_camera_profile(), drive, map_path=tif)
    stats = run.pipe.service.stats
    assert stats.crops_off_map >= 10 and stats.triggers_off_map >= 3, stats
    assert run.stats.fixes["accepted"] >= 2 and run.stats.fixes["no_results"] == stats.triggers_off_map
    on_map = run.t < 8.0  # crops 102 m wide: on the map until ~100 m east
    assert run.sigma[on_map].max() < 8.0 and run.sigma[-1] > 10.0
    assert np.all(run.errors <= 3.0 * run.sigma + 0.01)


def test_daemon_frozen_camera_degrades(tmp_path: Path) -> None:
    """Over loopback: a camera folder holding one frame repeated. After the first fix every trigger is a
    frozen frame; the accuracy grows and GPS_INPUT drops to fix_type 1 honestly."""
    folder = write_folder(tmp_path / "cam", [noise_image(3)] * 200)
    port = free_udp_port()
    daemon = Daemon(small_camera_profile(), DaemonOptions(connect=f"udpin:127.0.0.1:{port}",
                                                          camera=f"folder:{folder}@100"))
    daemon.start()
    time.sleep(0.2)
    ap = MiniAutopilot(port, boot_s=100.0)
    ap.start()
    time.sleep(11.0)
    daemon.stop()
    daemon.join(5.0)
    ap.stop()
    s = daemon.summary()
    assert daemon.exit_code == 0 and s["fixes"].get("frozen_frame", 0) >= 2 and s["fixes"].get("accepted", 0) <= 1
    gps = ap.of_type("GPS_INPUT")
    fix = np.array([r.msg.fix_type for r in gps])
    acc = np.array([r.msg.horiz_accuracy for r in gps])
    assert fix[-1] == 1 and acc[-1] > 10.0 and np.any(fix == 3)
    assert np.all(fix[acc > 10.0] == 1)  # never fix_type 3 with an accuracy worse than the degrade threshold
    texts = " ".join(r.msg.text for r in ap.of_type("STATUSTEXT"))
    assert "no fix: frozen_frame" in texts and "degraded: accuracy" in texts
    for r in gps:
        lat_t, lon_t = ap.truth_latlon(r.t - ap.t_start)
        proj = UtmProjector.for_latlon(lat_t, lon_t)
        e_t, n_t = proj.to_utm(lat_t, lon_t)
        e, n = proj.to_utm(r.msg.lat * 1e-7, r.msg.lon * 1e-7)
        assert math.hypot(e - e_t, n - n_t) <= 3.0 * r.msg.horiz_accuracy + 1.0
