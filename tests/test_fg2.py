"""FG2 adapter: loading errors, a TinyFg2 checkpoint through the real loading path, batch of five crops."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the fg2 extra (torch) is not installed")

from taco_mav.camera.geometry import GroundCamera  # noqa: E402
from taco_mav.config import CameraConfig, Fg2Config  # noqa: E402
from taco_mav.cvgl.base import Crop, GroundFrame  # noqa: E402
from taco_mav.cvgl.fg2.adapter import Fg2Matcher, _to_result, load_model, pixel_from_level  # noqa: E402
from taco_mav.cvgl.fg2.tiny import TinyFg2, save_tiny  # noqa: E402
from taco_mav.errors import MatcherError  # noqa: E402

TINY = "taco_mav.cvgl.fg2.tiny:build_model"
CAMERA = GroundCamera.from_config(CameraConfig(), scale=0.25)


def cfg_for(tmp_path: Path, entry: str = TINY) -> Fg2Config:
    (tmp_path / "checkout").mkdir(exist_ok=True)
    return Fg2Config(checkout=str(tmp_path / "checkout"), checkpoint=str(tmp_path / "tiny.pt"), device="cpu",
                     entry=entry)


def test_missing_checkout_and_checkpoint(tmp_path: Path) -> None:
    with pytest.raises(MatcherError, match="checkout.*not found"):
        load_model(Fg2Config(checkout=str(tmp_path / "nope"), checkpoint=str(tmp_path / "x.pt")))
    cfg = cfg_for(tmp_path)
    with pytest.raises(MatcherError, match=r"tiny\.pt.*not found"):
        load_model(cfg)
    (tmp_path / "tiny.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(MatcherError, match=r"tiny\.pt: cannot load checkpoint"):
        load_model(cfg)
    with pytest.raises(MatcherError, match="cannot import 'no_such_fg2_module'"):
        load_model(cfg_for(tmp_path, "no_such_fg2_module:build"))
    # the default entry checks the published FG2 layout
    with pytest.raises(MatcherError, match=r"not an FG2 checkout \(models/model_kitti.py not found\)"):
        load_model(cfg_for(tmp_path, Fg2Config().entry))


class CountingTiny(TinyFg2):
    """TinyFg2 counting encoder calls and batch sizes."""

    def __init__(self) -> None:
        super().__init__()
        self.ground_calls, self.batches = 0, []

    def encode_ground(self, image, ground_from_pixel, pixel_from_level):  # type: ignore[no-untyped-def]
        self.ground_calls += 1
        self.pixel_from_level = pixel_from_level
        return super().encode_ground(image, ground_from_pixel, pixel_from_level)

    def match_aerial(self, feats, aerial, m_per_px):  # type: ignore[no-untyped-def]
        self.batches.append(aerial.shape[0])
        return super().match_aerial(feats, aerial, m_per_px)


def inputs(seed: int = 0) -> tuple[GroundFrame, list[Crop]]:
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 255, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8)
    crops = [Crop(rng.integers(0, 255, (128, 128, 3), dtype=np.uint8), np.array([5e5 + i, 5.4e6]), 0.3, 0.4)
             for i in range(5)]
    return GroundFrame(image, 1.0, CAMERA), crops


def test_loaded_checkpoint_batch_of_five(tmp_path: Path) -> None:
    cfg = cfg_for(tmp_path)
    saved = save_tiny(tmp_path / "tiny.pt", seed=3)
    matcher = Fg2Matcher(cfg, CAMERA)
    for k, v in saved.state_dict().items():  # the loader restored the very weights the test wrote
        assert torch.equal(v, matcher.model.state_dict()[k])
    frame, crops = inputs()
    results = matcher.match(frame, crops)
    assert len(results) == 5
    for r in results:
        assert np.isfinite(r.t).all() and np.isfinite(r.R).all() and 0.0 < r.w <= 1.0
        assert np.allclose(r.R @ r.R.T, np.eye(2), atol=1e-6) and np.linalg.det(r.R) == pytest.approx(1.0)
        assert r.elapsed_s > 0.0
    again = matcher.match(frame, crops)  # deterministic inference
    assert all(np.allclose(a.t, b.t) and a.w == b.w for a, b in zip(results, again))


def test_ground_encoded_once_per_trigger(tmp_path: Path) -> None:
    model = CountingTiny().eval()
    matcher = Fg2Matcher(cfg_for(tmp_path), CAMERA, model=model)
    frame, crops = inputs(1)
    matcher.match(frame, crops)
    matcher.match(frame, crops)
    assert model.ground_calls == 2 and model.batches == [5, 5]
    assert model.pixel_from_level.shape == (1, 3, 3)
    with pytest.raises(MatcherError, match="share size"):
        matcher.match(frame, crops[:4] + [Crop(np.zeros((64, 64, 3), np.uint8), np.zeros(2), 0.3, 0.4)])


def test_image_frame_to_crop_frame_conversion() -> None:
    """A vehicle 10 px right and 20 px below the centre at 0.5 m/px is 10 m back and 5 m right; an image-frame
    rotation of -0.2 rad (counter-clockwise on screen) is a +0.2 rad (CCW) residual."""
    a = -0.2
    R_img = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    r = _to_result(R_img, np.array([10.0, 20.0]), 0.7, 0.5, 0.01)
    assert r.t == pytest.approx([-10.0, -5.0])
    assert math.atan2(r.R[1, 0], r.R[0, 0]) == pytest.approx(0.2)
    assert _to_result(R_img, np.array([np.nan, 0.0]), 0.7, 0.5, 0.0).w == pytest.approx(1e-3)
    assert _to_result(R_img, np.zeros(2), 0.0, 0.5, 0.0).w == pytest.approx(1e-3)


def test_pixel_from_level_is_the_camera_projection_with_pitch() -> None:
    """A ground point (forward f, left l) is (x, y, z) = (-l, h, f) in the level camera frame; K @ R_pitch must
    project it where the flat-ground homography does, for a pitched camera too."""
    cam = GroundCamera.from_config(CameraConfig(pitch_rad=0.08), scale=0.5)
    P = pixel_from_level(cam)
    for f, l in [(5.0, 0.0), (12.0, -3.0), (30.0, 8.0)]:
        a = P @ np.array([-l, cam.mount_height_m, f])
        b = cam.ground_to_image @ np.array([f, l, 1.0])
        np.testing.assert_allclose(a[:2] / a[2], b[:2] / b[2], atol=1e-9)
