"""Vehicle translation between two rendered camera frames (cvgl/ground_motion.py): the real renderer and
OpenCV's phase correlation on a textured flat world, straight and turning, and refusal of blank ground."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from rasterio.transform import from_origin

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig
from taco_mav.cvgl.ground_motion import GroundMotion, HeadingHistory
from taco_mav.datasets.synthetic.layout import Building, Scene
from taco_mav.datasets.synthetic.render import GroundRenderer
from taco_mav.datasets.synthetic.render3d import GlRenderer3D, Lighting
from taco_mav.datasets.synthetic.scene3d import MovingCars, build_scene3d

E0, N0, RES = 600_000.0, 5_400_000.0, 0.1


def _renderer(seed: int = 0, size: int = 2000, blank: bool = False) -> tuple[GroundRenderer, GroundCamera]:
    rng = np.random.default_rng(seed)
    tex = rng.integers(0, 255, (size // 8, size // 8, 3), dtype=np.uint8)
    mosaic = cv2.resize(tex, (size, size), interpolation=cv2.INTER_CUBIC)  # blobs of ~0.8 m, like asphalt patches
    mosaic = cv2.GaussianBlur(mosaic, (0, 0), 1.0)
    if blank:
        mosaic[:] = 90
    cam = GroundCamera.from_config(CameraConfig(width_px=640, height_px=360, fx=450.0, fy=450.0, cx=320.0, cy=180.0,
                                                mount_height_m=1.0, pitch_rad=0.2))
    return GroundRenderer(mosaic, from_origin(E0, N0 + size * RES, RES, RES), cam, levels=3), cam


@pytest.mark.parametrize("d_fwd,d_left,dtheta", [(0.8, 0.0, 0.0), (2.0, 0.1, 0.0), (1.2, 0.0, 0.06),
                                                 (0.3, -0.05, -0.03)])
def test_translation_between_rendered_frames(d_fwd: float, d_left: float, dtheta: float) -> None:
    r, cam = _renderer()
    gm = GroundMotion(cam)
    th = 0.7
    E, N = E0 + 100.0, N0 + 100.0
    c, s = math.cos(th), math.sin(th)
    f0 = r.render((E, N, th))
    f1 = r.render((E + c * d_fwd - s * d_left, N + s * d_fwd + c * d_left, th + dtheta))
    m = gm.measure(f0, f1, dtheta)
    assert m is not None
    assert abs(m.d_fwd - d_fwd) < 0.03 and abs(m.d_left - d_left) < 0.05, m
    assert m.sigma_m < 0.05 and m.response > 0.1


def test_standing_still_measures_zero_and_blank_ground_is_refused() -> None:
    r, cam = _renderer()
    gm = GroundMotion(cam)
    f0 = r.render((E0 + 100.0, N0 + 100.0, 0.0))
    m = gm.measure(f0, f0.copy())
    assert m is not None and abs(m.d_fwd) < 0.01 and abs(m.d_left) < 0.01
    rb, camb = _renderer(blank=True)
    gb = GroundMotion(camb)
    fb = rb.render((E0 + 100.0, N0 + 100.0, 0.0))
    assert gb.measure(fb, rb.render((E0 + 101.0, N0 + 100.0, 0.0))) is None


def _following_frames(gap_m: float, speed_mps: float = 8.0, dt: float = 0.2) -> tuple[np.ndarray, np.ndarray,
                                                                                        GroundCamera]:
    """Two frames dt apart, rendered by the 3-D world's OpenGL renderer: the vehicle drives east at speed_mps on
    asphalt (grey, low-contrast texture) behind a grey car (`car_mesh`: body, dark cabin, contact shadow) that
    drives at the same speed gap_m ahead."""
    res = 0.05
    rng = np.random.default_rng(4)
    tex = rng.normal(0.0, 1.0, (20 * 8, 100 * 8))
    grey = 92.0 + 10.0 * cv2.resize(cv2.GaussianBlur(tex, (0, 0), 1.5), (100 * 20, 20 * 20)) / 0.2
    ground = np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[:, :, None], 3, axis=2)
    far = Building(corners=np.array([[500.0, -5.0], [510.0, -5.0], [510.0, 5.0], [500.0, 5.0]]), height_m=5.0,
                   colour=(90, 90, 90), gable=False)
    layout = Scene(extent=(-50.0, -50.0, 550.0, 50.0), roads=[], junctions=np.zeros((0, 2)),
                   junction_style=np.zeros(0, int), junction_radius=np.zeros(0), buildings=[far])
    s3 = build_scene3d(layout, np.random.default_rng(0))
    s3.moving = MovingCars(np.array([[-50.0, 0.0], [550.0, 0.0]]), np.array([0, 2]), np.array([0.0]),
                           np.array([50.0 + gap_m]), np.array([speed_mps]), np.array([4]))  # CAR_RGB[4]: grey
    cam = GroundCamera.from_config(CameraConfig())
    gl = GlRenderer3D(s3, ground, (-10.0, 10.0), res, shadow_px=1024)
    try:
        f0, f1 = (gl.render_camera(cam, (speed_mps * t, 0.0, 0.0), t=t, light=Lighting(sun_az_deg=200.0))[0]
                  for t in (1.0, 1.0 + dt))
    finally:
        gl.close()
    return f0, f1, cam


def test_a_car_followed_at_constant_distance_is_outvoted_by_the_ground_beside_it() -> None:
    """A car 9 m ahead at our speed looks the same in both frames and fills the middle of the band: one patch
    across the middle (the measurement before strips) locks onto it and says the vehicle stood still; the strips
    beside it see the ground move and give the true 1.6 m."""
    pytest.importorskip("moderngl")
    f0, f1, cam = _following_frames(9.0)
    gm = GroundMotion(cam)
    one = GroundMotion(cam, band_m=gm.band_m, half_width_m=1.5, strips=1).measure(f0, f1)
    assert one is None or abs(one.d_fwd - 1.6) > 0.5, one  # the single patch is fooled (or gives up)
    m = gm.measure(f0, f1)
    assert m is not None and abs(m.d_fwd - 1.6) < 0.03 and abs(m.d_left) < 0.05, m


def test_strips_that_disagree_without_a_majority_give_no_answer() -> None:
    """The right half of the second frame is the first frame's (that half of the view stands still): two strips
    see 1.2 m, two see 0 and neither group outvotes the other, so there is no answer. With the right quarter
    frozen, three strips outvote one."""
    r, cam = _renderer(seed=3)
    f0, f1 = r.render((E0 + 100.0, N0 + 100.0, 0.0)), r.render((E0 + 101.2, N0 + 100.0, 0.0))
    gm = GroundMotion(cam, strips=4)
    m = gm.measure(f0, f1)
    assert m is not None and abs(m.d_fwd - 1.2) < 0.03
    cx = int(round(cam.K[0, 2]))
    half = f1.copy()
    half[:, cx:] = f0[:, cx:]
    assert gm.measure(f0, half) is None
    quarter = f1.copy()
    quarter[:, cx + 110:] = f0[:, cx + 110:]  # the ground from 2.7 m right (11 m ahead): most of the right strip
    m = gm.measure(f0, quarter)
    assert m is not None and abs(m.d_fwd - 1.2) < 0.03


def test_the_band_starts_above_the_rows_the_vehicle_hides() -> None:
    """KITTI's camera with a bonnet in the bottom 60 rows (it moves with the vehicle): the band starts farther
    out, where the ground is seen above them; a bonnet hiding the whole view is refused at start-up with a line
    naming the cause."""
    cam = GroundCamera.from_config(CameraConfig())
    plain, bonnet = GroundMotion(cam), GroundMotion(cam, ego_rows=60)
    G = cam.ground_to_image
    p = G @ np.array([bonnet.band_m[0] - bonnet.max_shift_m, 0.0, 1.0])
    assert bonnet.band_m[0] > plain.band_m[0] + 1.0 and p[1] / p[2] <= cam.height - 1 - 60
    with pytest.raises(ValueError, match="ground motion: the camera sees no ground"):
        GroundMotion(cam, ego_rows=cam.height - 5)

def test_heading_history_interpolates_across_the_wrap_and_restarts_after_the_clock_goes_back() -> None:
    """The heading change between two frame times: interpolated through +-pi (not the long way round), None more
    than 0.1 s outside what was recorded; a time more than 1 s earlier than the last (a reboot) starts afresh."""
    h = HeadingHistory()
    for k in range(11):  # 3.0 rad -> 3.0 + 0.05 * 10 = 3.5 rad, recorded wrapped to (-pi, pi]
        h.add(10.0 + 0.1 * k, math.remainder(3.0 + 0.05 * k, 2 * math.pi))
    assert h.change(10.05, 10.95) == pytest.approx(0.45, abs=1e-9)
    assert h.change(10.0, 11.05) == pytest.approx(0.5, abs=1e-9)  # just past the last: its value
    assert h.change(10.0, 11.2) is None
    assert h.change(9.8, 10.5) is None
    h.add(10.9, 0.0)  # not after the last, within 1 s: ignored
    assert h.at(11.0) == pytest.approx(math.remainder(3.5, 2 * math.pi), abs=1e-9)
    h.add(2.0, 1.0)  # the clock went back: the history restarts
    assert h.at(2.0) == 1.0 and h.at(10.5) is None
