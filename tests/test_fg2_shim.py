"""The default fg2 entry (published FG2 wrapper) end to end on a fake FG2 checkout written into tmp_path.

tests/fake_fg2 mirrors FG2's layout and interfaces (config.ini, models/model_kitti.py CVM, models/modules.py
DinoExtractor, utils/utils.py) with a tiny random network, because FG2's real weights are not available.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
import shutil
import sys
import types
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the fg2 extra (torch) is not installed")

from taco_mav.camera.geometry import GroundCamera  # noqa: E402
from taco_mav.config import CameraConfig, Fg2Config, Profile  # noqa: E402
from taco_mav.cvgl.base import Crop, GroundFrame  # noqa: E402
from taco_mav.cvgl.fg2.adapter import Fg2Matcher, load_model  # noqa: E402
from taco_mav.cvgl.fg2.published import PublishedFg2  # noqa: E402
from taco_mav.cvgl.fg2.shim import DINOV2_FILE, _load_cvm, fg2_import_scope, read_settings  # noqa: E402
from taco_mav.cvgl.registry import make_matcher  # noqa: E402
from taco_mav.errors import MatcherError  # noqa: E402

FAKE = Path(__file__).parent / "fake_fg2"
CAMERA = GroundCamera.from_config(CameraConfig(), scale=0.25)
STEP = 99.0 / 8  # metres between BEV points of the fake config (grid_size_h 99 m, sat_bev_res 9)


def make_checkpoint(checkout: Path, path: Path, planted: tuple[float, float, float] | None = None,
                    drop: tuple[str, ...] = ()) -> dict[str, torch.Tensor]:
    """Build the checkout's CVM with random weights (seed 123), optionally plant a pose, save its state_dict."""
    settings = read_settings(checkout / "config.ini")
    with fg2_import_scope(checkout, torch.device("cpu")):
        torch.manual_seed(123)
        cvm = importlib.import_module("models.model_kitti").CVM(
            "cpu", settings.grd_bev_res, settings.grd_height_res, settings.sat_bev_res, settings.grid_size_h,
            settings.grid_size_v)
    if planted is not None:
        cvm.planted.copy_(torch.tensor([1.0, *planted]))
    state = {k: v for k, v in cvm.state_dict().items() if k not in drop}
    torch.save(state, path)
    return state


def fake_dinov2_state(checkout: Path, seed: int = 5) -> dict[str, torch.Tensor]:
    """Random weights for the fake checkout's tiny ViT (its DINOv2 stand-in)."""
    with fg2_import_scope(checkout, torch.device("cpu")):
        torch.manual_seed(seed)
        return importlib.import_module("DINO_modules.dinov2").vit_large(patch_size=14).state_dict()


@pytest.fixture()
def checkout(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fake FG2 checkout, its checkpoint (tmp_path/model.pt) and DINOv2 weights next to the checkpoint."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))  # no DINOv2 in a real hub cache
    root = tmp_path / "FG2"
    shutil.copytree(FAKE, root)
    torch.save(fake_dinov2_state(root), tmp_path / DINOV2_FILE)
    make_checkpoint(root, tmp_path / "model.pt")
    return root


def cfg_for(checkout: Path, fast: bool = True) -> Fg2Config:
    return Fg2Config(checkout=str(checkout), checkpoint=str(checkout.parent / "model.pt"), device="cpu", fast=fast)


def inputs(seed: int = 0, size: int = 128, m_per_px: float = 0.8) -> tuple[GroundFrame, list[Crop]]:
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 255, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8)
    crops = [Crop(rng.integers(0, 255, (size, size, 3), dtype=np.uint8), np.array([5e5 + i, 5.4e6]), 0.3, m_per_px)
             for i in range(5)]
    return GroundFrame(image, 1.0, CAMERA), crops


def psi(r) -> float:
    return math.atan2(r.R[1, 0], r.R[0, 0])


def test_make_matcher_runs_the_checkout_on_five_crops(checkout: Path) -> None:
    profile = dataclasses.replace(Profile(), matcher="fg2", fg2=cfg_for(checkout), camera=CameraConfig())
    matcher = make_matcher(profile, camera=CAMERA)
    assert isinstance(matcher, Fg2Matcher) and isinstance(matcher.model, PublishedFg2)
    saved = torch.load(checkout.parent / "model.pt", weights_only=True)
    for k, v in saved.items():  # the shim restored the very weights the test wrote
        assert torch.equal(v, matcher.model.cvm.state_dict()[k]), k
    frame, crops = inputs()
    results = matcher.match(frame, crops)
    assert len(results) == 5
    for r in results:
        assert np.isfinite(r.t).all() and 0.0 < r.w <= 1.0 and r.elapsed_s > 0.0
        assert np.linalg.norm(r.t) < 99.0  # inside FG2's aerial square
        assert np.allclose(r.R @ r.R.T, np.eye(2), atol=1e-5) and np.linalg.det(r.R) == pytest.approx(1.0, abs=1e-5)
    again = matcher.match(frame, crops)  # FG2's sampling runs from a fixed seed: deterministic
    assert all(np.array_equal(a.t, b.t) and np.array_equal(a.R, b.R) and a.w == b.w for a, b in zip(results, again))
    assert len({round(float(r.t[0]), 6) for r in results}) > 1  # different crops, different answers


@pytest.mark.parametrize("planted, t_expected, psi_expected, full", [
    # FG2 frame: ground = R(a) aerial + t, (row down, col right) metres; the vehicle is at -t (FG2's evaluation).
    ((-math.pi / 2, -2 * STEP, 0.0), (-2 * STEP, 0.0), math.pi / 2, True),
    ((math.pi / 2, -STEP, 2 * STEP), (-STEP, 2 * STEP), -math.pi / 2, False),
])
def test_planted_fg2_pose_becomes_the_expected_match_result(checkout: Path, planted, t_expected, psi_expected,
                                                            full: bool) -> None:
    """vehicle (row, col) = -t, i.e. (forward, left) = (t_row, t_col); an FG2 rotation a (aerial -> ground, (row,
    col) axes) is a residual heading psi = -a (CCW); w = coupling mass on the pose / ground cells seen."""
    make_checkpoint(checkout, checkout.parent / "model.pt", planted=planted)
    matcher = Fg2Matcher(cfg_for(checkout, fast=False), CAMERA)  # the planted coupling is in FG2's own forward
    frame, crops = inputs(1)
    for r in matcher.match(frame, crops):
        np.testing.assert_allclose(r.t, t_expected, atol=1e-3)
        assert psi(r) == pytest.approx(psi_expected, abs=1e-5)
        if full:  # every seen ground cell has its exact aerial partner: w is the planted mass
            assert r.w == pytest.approx(0.8, abs=1e-5)
        else:
            assert 0.05 < r.w < 0.8


def test_checkpoint_without_grid_queries_gets_fg2s_seeded_values(checkout: Path) -> None:
    """A checkpoint trained on CUDA lacks grd_grid_queries; FG2's test script then uses the values drawn after
    seeding and building DinoExtractor; the shim reproduces them."""
    make_checkpoint(checkout, checkout.parent / "model.pt", drop=("grd_grid_queries",))
    model = load_model(cfg_for(checkout))
    dino = torch.load(checkout.parent / DINOV2_FILE, weights_only=True)
    with fg2_import_scope(checkout, torch.device("cpu")):
        torch.manual_seed(0)
        importlib.import_module("models.modules").DinoExtractor(dinov2_weights=dino)
        expected = torch.rand(5, 9, model.cvm.embed_dim)
    assert torch.equal(model.cvm.grd_grid_queries.detach(), expected)


def test_import_scope_restores_the_process(checkout: Path) -> None:
    sentinel = types.ModuleType("utils")
    sys.modules["utils"] = sentinel
    try:
        cwd, path = os.getcwd(), list(sys.path)
        det = torch.are_deterministic_algorithms_enabled()
        torch.manual_seed(42)
        load_model(cfg_for(checkout))  # FG2's imports seed and switch deterministic algorithms on
        assert os.getcwd() == cwd and sys.path == path and sys.modules["utils"] is sentinel
        assert "models" not in sys.modules and torch.are_deterministic_algorithms_enabled() == det
        drawn = torch.rand(3)
        torch.manual_seed(42)
        assert torch.equal(drawn, torch.rand(3))  # the caller's RNG stream is untouched
    finally:
        sys.modules.pop("utils", None)


def test_crops_resampled_to_fg2s_extent_with_the_centre_kept(checkout: Path) -> None:
    """A 128 px crop at 1 m/px: FG2 sees its central 99 m at 84 px; a bright block 20 m right of and 10 m above
    the crop centre lands 20 m right / 10 m above the centre of FG2's input."""
    model = load_model(cfg_for(checkout))
    crop = torch.zeros(1, 3, 128, 128)
    c = 63.5
    crop[..., int(c - 10 - 2):int(c - 10 + 3), int(c + 20 - 2):int(c + 20 + 3)] = 1.0
    out = model.aerial_input(crop, 1.0)[0, 0]
    assert out.shape == (84, 84)
    ys, xs = torch.meshgrid(torch.arange(84.0), torch.arange(84.0), indexing="ij")
    m_per_px = 99.0 / 84
    cy, cx = (out * ys).sum() / out.sum(), (out * xs).sum() / out.sum()
    assert float((cx - 41.5) * m_per_px) == pytest.approx(20.0, abs=0.6)
    assert float((41.5 - cy) * m_per_px) == pytest.approx(10.0, abs=0.6)
    with pytest.raises(MatcherError, match=r"crops cover 51.2 m but FG2 .*grid_size_h.* needs 99 m"):
        model.aerial_input(torch.zeros(1, 3, 64, 64), 0.8)


def test_each_missing_piece_is_named(checkout: Path, tmp_path: Path) -> None:
    cfg = cfg_for(checkout)
    with pytest.raises(MatcherError, match="checkout.*not found"):
        load_model(dataclasses.replace(cfg, checkout=str(tmp_path / "nowhere")))
    # DINOv2 weights: none next to the checkpoint, in the checkout or in torch's hub cache
    (checkout.parent / DINOV2_FILE).rename(tmp_path / "elsewhere.pth")
    with pytest.raises(MatcherError, match=r"DINOv2 ViT-L/14 weights dinov2_vitl14_pretrain.pth not found.*"
                                           r"next to fg2.checkpoint"):
        load_model(cfg)
    (tmp_path / "elsewhere.pth").rename(checkout / DINOV2_FILE)  # the checkout root is a searched place
    assert isinstance(load_model(cfg), PublishedFg2)
    # checkpoint unreadable, or not FG2's
    (checkout.parent / "model.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(MatcherError, match=r"model\.pt: cannot load fg2.checkpoint"):
        load_model(cfg)
    torch.save({"other.weight": torch.zeros(2)}, checkout.parent / "model.pt")
    with pytest.raises(MatcherError, match=r"model\.pt: does not fit FG2's CVM \(missing keys .*dustbin_score"):
        load_model(cfg)
    make_checkpoint(checkout, checkout.parent / "model.pt")
    # settings: a key kitti_train_test.py needs
    ini = checkout / "config.ini"
    text = ini.read_text()
    ini.write_text(text.replace("sat_bev_res = 9\n", ""))
    with pytest.raises(MatcherError, match=r"config\.ini: \[Model\] sat_bev_res"):
        load_model(cfg)
    ini.write_text(text)
    # FG2's dependencies: mmcv not installed
    module = checkout / "models" / "model_kitti.py"
    source = module.read_text()
    module.write_text("import einops_not_installed_here\n" + source)
    with pytest.raises(MatcherError, match=r"needs the module 'einops_not_installed_here', which is not installed: "
                                           r"pip install einops_not_installed_here"):
        load_model(cfg)
    module.write_text(source)
    # an incomplete checkout
    shutil.rmtree(checkout / "utils")
    with pytest.raises(MatcherError, match=r"is incomplete: importing models.model_kitti needs utils"):
        load_model(cfg)
    module.unlink()
    with pytest.raises(MatcherError, match=r"not an FG2 checkout \(models/model_kitti.py not found\)"):
        load_model(cfg)


def test_grid_queries_of_a_cuda_built_model_are_copied_by_hand(checkout: Path) -> None:
    """Built on CUDA, FG2's CVM holds grd_grid_queries as a plain tensor (not in its state_dict); a checkpoint
    that has them must still set them."""
    state = make_checkpoint(checkout, checkout.parent / "model.pt")
    settings = read_settings(checkout / "config.ini")
    with fg2_import_scope(checkout, torch.device("cpu")):
        cvm = importlib.import_module("models.model_kitti").CVM(
            "cpu", settings.grd_bev_res, settings.grd_height_res, settings.sat_bev_res, settings.grid_size_h,
            settings.grid_size_v)
    plain = cvm._parameters.pop("grd_grid_queries").detach().clone()
    cvm.grd_grid_queries = plain  # what .to("cuda") leaves behind
    assert "grd_grid_queries" not in cvm.state_dict()
    _load_cvm(cvm, dict(state), checkout.parent / "model.pt")
    assert torch.equal(cvm.grd_grid_queries, state["grd_grid_queries"])
    assert torch.equal(cvm.dustbin_score.detach(), state["dustbin_score"])
