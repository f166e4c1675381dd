"""Masks for what IPM cannot represent: a synthetic vertical occluder in a real rendered frame is found and kept
out of the bird's-eye view, clean ground is not masked, real KITTI frames keep their road."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rasterio.transform import from_origin

from taco_mav.bench.classical import NORTH, WEST, textured_mosaic
from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig, ClassicalMatcherConfig
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.cvgl.classical import ClassicalMatcher
from taco_mav.cvgl.ipm import BevProjector
from taco_mav.cvgl.masks import (
    MaskOptions,
    _fill_between,
    _gradient_bands,
    horizon_row,
    image_mask,
    vegetation_mask,
    vertical_structure_mask,
)
from taco_mav.datasets.synthetic.gap import FrameGap, occlude_frame
from taco_mav.datasets.synthetic.render import GroundRenderer

KITTI_IMAGES = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_images"
BOX = FrameGap(count=1, width_m=(1.5, 2.0), height_m=(3.0, 4.0), fwd_m=(10.0, 12.0), left_m=(3.0, 5.0))


@pytest.fixture(scope="module")
def scene() -> tuple[GroundCamera, list[np.ndarray]]:
    """The KITTI camera and four frames rendered from the bench's textured mosaic at seeded poses."""
    cam = GroundCamera.from_config(CameraConfig())
    mosaic = textured_mosaic(4, 1500, 0.2)
    renderer = GroundRenderer(mosaic, from_origin(WEST, NORTH, 0.2, 0.2), cam, max_range_m=80.0)
    rng = np.random.default_rng(1)
    frames = [renderer.render((WEST + rng.uniform(120, 180), NORTH - rng.uniform(120, 180), rng.uniform(-3, 3)))
              for _ in range(4)]
    return cam, frames


def test_clean_ground_is_not_masked(scene) -> None:
    cam, frames = scene
    for f in frames:
        assert vertical_structure_mask(f, cam).mean() < 0.01


def test_a_vertical_occluder_is_found_and_excluded_from_the_bev(scene) -> None:
    """One upright box 10-12 m ahead, 3-5 m left: most of its pixels below the horizon are masked, little else;
    in the bird's-eye view the mask covers most of the box's smear (what IPM would paint onto the ground)."""
    cam, frames = scene
    bev = BevProjector(cam, (135, 70), 0.6, 40.0)
    vh = int(np.ceil(horizon_row(cam)))
    for k, f in enumerate(frames):
        img, box = occlude_frame(f, cam, seed=k, gap=BOX)
        m = vertical_structure_mask(img, cam)
        below = np.zeros_like(box)
        below[vh:] = True
        assert (m & box & below).sum() >= 0.6 * (box & below).sum(), k
        assert (m & ~box & below).sum() <= 0.02 * (~box & below).sum(), k
        smear = (bev.project(box.astype(np.float32))[0] > 0.5) & bev.mask
        hidden = (bev.project(m.astype(np.float32))[0] >= 0.25) & bev.mask
        assert (smear & hidden).sum() >= 0.6 * smear.sum(), k


def test_the_matcher_keeps_masked_pixels_out_of_its_template(scene) -> None:
    cam, frames = scene
    matcher = ClassicalMatcher(ClassicalMatcherConfig(), cam)
    crop_rgb = cv2.resize(frames[0], (200, 200))  # any square RGB crop: only the mask bookkeeping is asserted
    crop = Crop(crop_rgb, np.zeros(2), 0.0, 0.6)
    matcher.match(GroundFrame(frames[0], 0.0, cam), [crop])
    assert matcher.last_mask_fraction == 1.0
    img, _ = occlude_frame(frames[0], cam, seed=0, gap=BOX)
    matcher.match(GroundFrame(img, 0.0, cam), [crop])
    assert 0.5 < matcher.last_mask_fraction < 0.98


def test_ego_rows_are_masked() -> None:
    cam = GroundCamera.from_config(CameraConfig())
    flat = np.full((cam.height, cam.width, 3), 100, np.uint8)
    assert image_mask(flat, cam) is None
    m = image_mask(flat, cam, MaskOptions(ego_rows=30))
    assert m is not None and m[-30:].all() and not m[:-30].any()


def test_real_kitti_frames_keep_their_road() -> None:
    """Three real KITTI frames (object benchmark, no pose): the mask finds structure (poles, door frames, building
    edges) in the frames that have it and never covers the road in front of the car (bottom 60 rows)."""
    paths = sorted(KITTI_IMAGES.glob("*.png"))
    if not paths:
        pytest.skip(f"no KITTI frames in {KITTI_IMAGES}")
    cam = GroundCamera.from_config(CameraConfig())
    found = 0
    for p in paths:
        img = cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB)
        img = cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        m = vertical_structure_mask(img, cam)
        assert m[-60:].mean() < 0.05, p.name
        assert m.mean() < 0.35, p.name
        found += m.mean() > 0.02
    assert found >= 2


def _colour_gradient(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_gradient_bands` put together: (gx, gy) float32 (H, W) each."""
    gx_out = np.full(image.shape[:2], np.nan, np.float32)
    gy_out = np.full(image.shape[:2], np.nan, np.float32)
    for r0, r1, gx, gy in _gradient_bands(image):
        gx_out[r0:r1], gy_out[r0:r1] = gx, gy
    return gx_out, gy_out


def _whole_image_gradient(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The gradient computed in one piece (its definition before it went by bands)."""
    img = cv2.GaussianBlur(image.astype(np.float32), (5, 5), 1.0)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    if img.ndim == 2:
        return gx, gy
    k = np.argmax(gx * gx + gy * gy, axis=2)[:, :, None]
    return np.take_along_axis(gx, k, axis=2)[:, :, 0], np.take_along_axis(gy, k, axis=2)[:, :, 0]


@pytest.mark.parametrize("shape", [(720, 1280, 3), (375, 1242, 3), (130, 40, 3), (65, 33, 3), (64, 10, 3),
                                   (5, 7, 3), (1, 9, 3), (67, 20), (3, 3)])
def test_the_gradient_by_bands_is_the_whole_image_gradient_bit_for_bit(shape: tuple[int, ...]) -> None:
    """Bands with a 3-row halo see what the whole image gives each row: equal float32 arrays, every size (a band
    boundary inside, on or beyond the image; grey and colour)."""
    rng = np.random.default_rng(sum(shape))
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    image[:, : shape[1] // 3] //= 4  # an edge as well as noise
    gx, gy = _colour_gradient(image)
    rx, ry = _whole_image_gradient(image)
    assert gx.dtype == np.float32 and gx.shape == shape[:2]
    np.testing.assert_array_equal(gx, rx)
    np.testing.assert_array_equal(gy, ry)


def test_the_gradient_of_rendered_frames_is_the_whole_image_gradient(scene) -> None:
    _, frames = scene
    for frame in frames:
        for got, want in zip(_colour_gradient(frame), _whole_image_gradient(frame)):
            np.testing.assert_array_equal(got, want)


def _whole_image_mask(image: np.ndarray, camera: GroundCamera, opts: MaskOptions = MaskOptions()) -> np.ndarray:
    """`vertical_structure_mask` computed on whole-frame arrays (its definition before it classified by bands)."""
    gx, gy = _whole_image_gradient(image)
    H, W = gx.shape
    tilt = np.tan(np.radians(opts.max_tilt_deg))
    agx = np.abs(gx)
    vertical = np.abs(gy) <= float(tilt) * agx
    vh, cx = horizon_row(camera), float(camera.K[0, 2])
    u = np.arange(W, dtype=np.float32)[None, :]
    v = np.arange(H, dtype=np.float32)[:, None]
    cone = (v > vh) & (np.abs(u - cx) <= float(tilt) * (v - vh) + 2.0)
    line = np.ones((max(5, int(round(opts.min_len_frac * H))), 1), np.uint8)
    strong = cv2.morphologyEx((vertical & ~cone & (agx >= opts.min_contrast)).astype(np.uint8), cv2.MORPH_OPEN, line)
    weak = cv2.morphologyEx((vertical & ~cone & (agx >= opts.min_contrast / 3.0)).astype(np.uint8),
                            cv2.MORPH_OPEN, line) | strong
    n, labels = cv2.connectedComponents(weak, connectivity=8)
    keep = np.zeros(n, bool)
    keep[np.unique(labels[strong > 0])] = True
    keep[0] = False
    runs = keep[labels]
    has = runs.any(axis=0)
    if not has.any():
        return np.zeros((H, W), bool)
    foot = np.where(has, H - 1 - np.argmax(runs[::-1], axis=0), -1)
    foot = _fill_between(foot, max(2, int(round(opts.fill_frac * W))), max(2.0, opts.foot_tol_frac * H))
    out = (np.arange(H)[:, None] <= foot[None, :]).astype(np.uint8)
    return cv2.dilate(out, np.ones((2 * opts.dilate_px + 1,) * 2, np.uint8)).astype(bool)


def test_the_mask_by_bands_is_the_whole_frame_mask_bit_for_bit(scene) -> None:
    """Classifying the gradient band by band (the daemon's peak memory) masks exactly the pixels the whole-frame
    arrays do: rendered frames with and without an occluder, and the real KITTI frames."""
    cam, frames = scene
    images = [f for k, f in enumerate(frames) for f in (f, occlude_frame(f, cam, seed=k, gap=BOX)[0])]
    for p in sorted(KITTI_IMAGES.glob("*.png")):
        img = cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB)
        images.append(cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA))
    masked = 0
    for img in images:
        got = vertical_structure_mask(img, cam)
        np.testing.assert_array_equal(got, _whole_image_mask(img, cam))
        masked += got.mean() > 0.01
    assert masked >= 4  # the occluded frames and the KITTI frames with structure: not all-clear comparisons


def test_standing_vegetation_is_masked_from_its_foot_up_and_a_lawn_is_not(scene) -> None:
    """A green blob that reaches above the horizon (a tree) is masked from its lowest pixel up in its columns; a
    green patch below the horizon (a lawn) and a grey frame are not; off by default."""
    cam, frames = scene
    img = np.full_like(frames[0], 110)
    vh = int(np.ceil(horizon_row(cam)))
    H = img.shape[0]
    img[vh - 40:vh + 30, 100:160] = (40, 140, 40)  # a tree whose foot is 30 rows below the horizon
    img[H - 60:H - 20, 600:800] = (60, 150, 50)  # a lawn
    opts = MaskOptions(vegetation=True)
    m = vegetation_mask(img, cam, opts)
    assert m[: vh + 28, 104:156].all()  # the tree and everything above its foot in its columns
    assert not m[vh + 40:, 104:156].any()  # ground nearer than its foot
    assert not m[H - 60:, 600:800].any()  # the lawn lies on the ground
    assert not vegetation_mask(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), cam, opts).any()
    assert image_mask(img, cam, MaskOptions(vertical=False)) is None
    assert image_mask(img, cam, MaskOptions(vertical=False, vegetation=True))[vh, 120]
