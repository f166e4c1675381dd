"""The fast FG2 path against FG2's own forward, the mmcv stand-in against the deformable-attention formula, the
CPU path's finiteness, torch.compile after the import scope.

The fake checkout (tests/fake_fg2) carries FG2's CVM forward and its KITTI attention modules verbatim at toy
scale. Where FG2_CHECKOUT names a real vita-epfl/FG2 checkout, the same equality is checked on FG2's own model
with random weights (slow on a CPU: minutes).
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the fg2 extra (torch) is not installed")

from taco_mav.camera.geometry import GroundCamera  # noqa: E402
from taco_mav.config import CameraConfig, Fg2Config  # noqa: E402
from taco_mav.cvgl.base import Crop, GroundFrame  # noqa: E402
from taco_mav.cvgl.fg2 import fast as fg2_fast  # noqa: E402
from taco_mav.cvgl.fg2.adapter import Fg2Matcher, pixel_from_level  # noqa: E402
from taco_mav.cvgl.fg2.mmcv import MultiScaleDeformableAttention, multi_scale_deformable_attn_pytorch  # noqa: E402
from taco_mav.cvgl.fg2.shim import build_random_model  # noqa: E402

FAKE = Path(__file__).parent / "fake_fg2"
CAMERA = GroundCamera.from_config(CameraConfig(), scale=0.25)
TOL = 1e-5  # fp32 reorderings (batched vs looped, broadcast vs repeated, SDPA vs hand-written softmax)


def inputs(seed: int = 0, size: int = 128, m_per_px: float = 0.8, camera: GroundCamera = CAMERA,
           n: int = 5) -> tuple[GroundFrame, list[Crop]]:
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 255, (camera.height, camera.width, 3), dtype=np.uint8)
    crops = [Crop(rng.integers(0, 255, (size, size, 3), dtype=np.uint8), np.array([5e5 + i, 5.4e6]), 0.3, m_per_px)
             for i in range(n)]
    return GroundFrame(image, 1.0, camera), crops


def reference_msda(value: torch.Tensor, shapes: list[tuple[int, int]], loc: torch.Tensor,
                   weights: torch.Tensor) -> torch.Tensor:
    """Deformable attention as mmcv's CUDA kernel computes it, point by point: bilinear sampling at (x W - 0.5,
    y H - 0.5), zero outside the map, points with non-finite coordinates skipped."""
    bs, _, heads, dim = value.shape
    _, nq, _, levels, points, _ = loc.shape
    out = torch.zeros(bs, nq, heads, dim, dtype=torch.float64)
    starts = np.cumsum([0] + [h * w for h, w in shapes])
    for b in range(bs):
        for q in range(nq):
            for m in range(heads):
                for lv, (H, W) in enumerate(shapes):
                    fmap = value[b, starts[lv]:starts[lv + 1], m].double().reshape(H, W, dim)
                    for p in range(points):
                        x, y = float(loc[b, q, m, lv, p, 0]) * W - 0.5, float(loc[b, q, m, lv, p, 1]) * H - 0.5
                        if not (y > -1 and x > -1 and y < H and x < W):  # the kernel's test (False for NaN)
                            continue
                        x0, y0 = math.floor(x), math.floor(y)
                        acc = torch.zeros(dim, dtype=torch.float64)
                        corners = ((y0, x0, (y0 + 1 - y) * (x0 + 1 - x)), (y0, x0 + 1, (y0 + 1 - y) * (x - x0)),
                                   (y0 + 1, x0, (y - y0) * (x0 + 1 - x)), (y0 + 1, x0 + 1, (y - y0) * (x - x0)))
                        for yy, xx, wgt in corners:
                            if 0 <= yy < H and 0 <= xx < W:
                                acc += wgt * fmap[yy, xx]
                        out[b, q, m] += float(weights[b, q, m, lv, p]) * acc
    return out.reshape(bs, nq, heads * dim)


def test_stand_in_deformable_attention_is_the_cuda_kernels_formula() -> None:
    gen = torch.Generator().manual_seed(0)
    shapes = [(3, 5), (2, 4)]
    value = torch.randn(2, sum(h * w for h, w in shapes), 2, 3, generator=gen)
    loc = torch.rand(2, 4, 2, 2, 3, 2, generator=gen) * 1.6 - 0.3  # some points outside the map
    loc[0, 0, 0, 0, 0] = torch.tensor([float("nan"), 0.5])  # FG2's depth-0 ground row: NaN and inf pixels
    loc[1, 2, 1, 1, 2] = torch.tensor([float("inf"), 0.5])
    loc[1, 3, 0, 0, 1] = torch.tensor([0.5, -float("inf")])
    weights = torch.rand(2, 4, 2, 2, 3, generator=gen)
    got = multi_scale_deformable_attn_pytorch(value, torch.tensor(shapes), loc, weights)
    assert torch.isfinite(got).all()
    torch.testing.assert_close(got.double(), reference_msda(value, shapes, loc, weights), atol=1e-5, rtol=1e-5)


def test_stand_in_module_has_mmcvs_parameters_and_init() -> None:
    m = MultiScaleDeformableAttention(embed_dims=16, num_heads=8, num_levels=1, num_points=4, batch_first=True)
    assert sorted(m.state_dict()) == ["attention_weights.bias", "attention_weights.weight", "output_proj.bias",
                                      "output_proj.weight", "sampling_offsets.bias", "sampling_offsets.weight",
                                      "value_proj.bias", "value_proj.weight"]
    ring = m.sampling_offsets.bias.view(8, 1, 4, 2)
    assert torch.allclose(ring[0, 0, :, 0], torch.tensor([1.0, 2.0, 3.0, 4.0])) and float(ring[2, 0, 0, 1]) == 1.0


@pytest.fixture(scope="module")
def fake_model():
    return build_random_model(FAKE, "cpu", seed=3)


def coupling_both_ways(model, frame: GroundFrame, crops: list[Crop]) -> dict[bool, tuple[torch.Tensor, ...]]:
    out = {}
    image = torch.from_numpy(frame.image).permute(2, 0, 1)[None].float() / 255
    aerial = torch.from_numpy(np.stack([c.image for c in crops])).permute(0, 3, 1, 2).float() / 255
    K = torch.as_tensor(pixel_from_level(frame.camera), dtype=torch.float32)[None]
    with torch.inference_mode():
        for fast in (True, False):
            model.set_fast(fast)
            feats = model.encode_ground(image, None, K)
            sat = model.extractor(model.aerial_input(aerial, crops[0].m_per_px))
            if fast:
                out[fast] = fg2_fast.coupling(model.cvm, fg2_fast.aerial_descriptors(model.cvm, sat), feats.desc,
                                              feats.keep)
            else:
                B = len(crops)
                out[fast] = model.cvm(feats.feature.repeat(B, 1, 1, 1), sat, feats.camera_k.repeat(B, 1, 1))
    model.set_fast(True)
    return out


def assert_same_results(a, b, tol: float) -> float:
    worst = 0.0
    for ra, rb in zip(a, b):
        for x, y in ((ra.t, rb.t), (ra.R, rb.R), (np.array([ra.w]), np.array([rb.w]))):
            worst = max(worst, float(np.abs(x - y).max()))
    assert worst <= tol, worst
    return worst


def test_fast_path_equals_fg2s_forward_on_the_fake_checkout(fake_model, tmp_path: Path) -> None:
    frame, crops = inputs(2)
    both = coupling_both_ways(fake_model, frame, crops)
    (fast_score, fast_raw), (slow_score, slow_raw) = both[True], both[False]
    assert torch.isfinite(fast_score).all() and torch.isfinite(slow_score).all()
    assert torch.equal(torch.isfinite(fast_raw), torch.isfinite(slow_raw))  # same ground cells seen
    diff = float((fast_score - slow_score).abs().max())
    assert diff < TOL, diff
    finite = torch.isfinite(slow_raw)
    assert float((fast_raw[finite] - slow_raw[finite]).abs().max()) < 1e-4
    # and through the matcher: poses and weights (Procrustes on the sampled pairs) the same
    cfg = Fg2Config(checkout=str(tmp_path), checkpoint="x", device="cpu")
    fast = Fg2Matcher(cfg, CAMERA, model=fake_model).match(frame, crops)
    fake_model.set_fast(False)
    slow = Fg2Matcher(Fg2Config(checkout=str(tmp_path), checkpoint="x", device="cpu", fast=False), CAMERA,
                      model=fake_model).match(frame, crops)
    fake_model.set_fast(True)
    worst = assert_same_results(fast, slow, 1e-4)
    print(f"fake checkout: max |coupling fast - published| = {diff:.3g}, max |t, R, w difference| = {worst:.3g}")


def test_fast_path_runs_the_ground_branch_once_and_heights_in_one_call(fake_model) -> None:
    """Per trigger of five crops: one ground self-attention call per round with batch 1, one deformable
    cross-attention call per round (all heights), against five-crop batches and one call per height in FG2's."""
    calls: list[tuple[str, int, int]] = []
    hooks = []
    for k in range(1, 7):
        for name in (f"grd_attention_self{k}", f"grd_attention_cross{k}"):
            attn = getattr(fake_model.cvm, name)
            inner = attn.grd_attention_self if "self" in name else attn.grd_attention_cross
            hooks.append(inner.register_forward_pre_hook(
                lambda mod, args, kw, n=name: calls.append((n, kw["query"].shape[0], kw["query"].shape[1])),
                with_kwargs=True))
    try:
        frame, crops = inputs(3)
        both_calls = {}
        for fast in (True, False):
            calls.clear()
            fake_model.set_fast(fast)
            Fg2Matcher(Fg2Config(checkout="x", checkpoint="x", device="cpu", fast=fast), CAMERA,
                       model=fake_model).match(frame, crops)
            both_calls[fast] = list(calls)
    finally:
        fake_model.set_fast(True)
        for h in hooks:
            h.remove()
    heights, cells = fake_model.settings.grd_height_res, (9 // 2 + 1) * 9
    fast_cross = [c for c in both_calls[True] if "cross" in c[0]]
    assert len(fast_cross) == 6 and all(c[1:] == (1, heights * cells) for c in fast_cross)
    assert all(c[1] == 1 for c in both_calls[True])
    slow_cross = [c for c in both_calls[False] if "cross" in c[0]]
    assert len(slow_cross) == 6 * heights and all(c[1:] == (5, cells) for c in slow_cross)


def test_sdpa_replaces_dinov2s_attention_and_can_be_undone(fake_model) -> None:
    attn = fake_model.extractor.dinov2_vitl14.blocks[0].attn
    assert "forward" in vars(attn)  # fast path: SDPA
    x = torch.randn(2, 7, 32)
    with torch.inference_mode():
        fast = attn(x)
        fake_model.set_fast(False)
        assert "forward" not in vars(attn)
        slow = attn(x)
        fake_model.set_fast(True)
    torch.testing.assert_close(fast, slow, atol=1e-5, rtol=1e-5)


def test_cpu_gives_finite_correct_results(fake_model) -> None:
    """On a CPU every crop gets a finite pose and mass: FG2's ground row at the camera (depth 0) projects to
    non-finite pixels, which the stand-in skips as mmcv's CUDA kernel does (mmcv's own CPU path turned the
    whole coupling into NaN, hence w = 0.001 for every fix), and the coupling is a proper dual-softmax
    coupling."""
    frame, crops = inputs(4)
    image = torch.from_numpy(frame.image).permute(2, 0, 1)[None].float() / 255
    aerial = torch.from_numpy(np.stack([c.image for c in crops])).permute(0, 3, 1, 2).float() / 255
    K = torch.as_tensor(pixel_from_level(CAMERA), dtype=torch.float32)[None]
    for fast in (True, False):
        fake_model.set_fast(fast)
        with torch.inference_mode():
            R, t, mass = fake_model.match_aerial(fake_model.encode_ground(image, None, K), aerial, 0.8)
        assert torch.isfinite(R).all() and torch.isfinite(t).all() and torch.isfinite(mass).all()
        assert ((mass >= 0) & (mass <= 1)).all()
    fake_model.set_fast(True)
    score, raw = coupling_both_ways(fake_model, frame, crops)[True]
    assert torch.isfinite(score).all() and (score >= 0).all()
    assert float(score.sum(2).max()) <= 1 + 1e-5 and float(score.sum(1).max()) <= 1 + 1e-5
    assert torch.isfinite(raw).any()


def test_camera_k_is_fp32_under_autocast(fake_model) -> None:
    frame, _ = inputs(5)
    image = torch.from_numpy(frame.image).permute(2, 0, 1)[None].float() / 255
    K = torch.as_tensor(pixel_from_level(CAMERA), dtype=torch.float32)[None]
    with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16):
        feats = fake_model.encode_ground(image, None, K)
    assert feats.camera_k.dtype == torch.float32 and feats.desc.dtype == torch.float32
    gh, gw = fake_model.settings.ground_size
    expected = torch.diag(torch.tensor([gw / CAMERA.width, gh / CAMERA.height, 1.0])) @ K
    torch.testing.assert_close(feats.camera_k, expected, rtol=0, atol=0)


def test_torch_compile_traces_fg2_modules_after_the_import_scope(fake_model) -> None:
    """FG2's modules leave sys.modules under their bare names; torch.compile's guards look modules up by name,
    which the private re-registration keeps working."""
    vit = fake_model.extractor.dinov2_vitl14
    module_name = type(vit.blocks[0].attn).__module__
    assert module_name.startswith("taco_mav_fg2_") and module_name in sys.modules
    torch._dynamo.reset()
    compiled = torch.compile(vit.forward_features, backend="eager", dynamic=False, fullgraph=False)
    x = torch.rand(1, 3, 56, 84)
    with torch.inference_mode():
        got = compiled(x)["x_norm_patchtokens"]
        want = vit.forward_features(x)["x_norm_patchtokens"]
    torch.testing.assert_close(got, want)
    torch._dynamo.reset()


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("FG2_CHECKOUT"), reason="FG2_CHECKOUT (a vita-epfl/FG2 checkout) not set")
def test_fast_path_equals_fg2s_forward_on_the_real_checkout() -> None:
    """FG2's own model, random weights (seed 0), KITTI sizes, on FG2_DEVICE (default cpu). The CVM on seeded
    random DINOv2-shaped features (ground 26 x 88, two crops 36 x 36) and the KITTI camera; DINOv2 (ViT-L/14, fp32
    on a CPU, fp16 on CUDA) with and without SDPA on a small image (a full-size ViT-L pass takes minutes on a
    CPU)."""
    device = torch.device(os.environ.get("FG2_DEVICE", "cpu"))
    model = build_random_model(Path(os.environ["FG2_CHECKOUT"]), device, seed=0)
    gen = torch.Generator().manual_seed(7)
    grd = torch.randn(1, 1024, 26, 88, generator=gen).to(device)
    sat = torch.randn(2, 1024, 36, 36, generator=gen).to(device)
    camera = GroundCamera.from_config(CameraConfig())
    gh, gw = model.settings.ground_size
    K = torch.as_tensor(pixel_from_level(camera), dtype=torch.float32)[None]
    camera_k = (torch.diag(torch.tensor([gw / camera.width, gh / camera.height, 1.0])) @ K).to(device)
    with torch.inference_mode():
        desc, keep = fg2_fast.ground_branch(model.cvm, grd, camera_k, model.settings.ground_size)
        fast_score, fast_raw = fg2_fast.coupling(model.cvm, fg2_fast.aerial_descriptors(model.cvm, sat), desc, keep)
        slow_score, slow_raw = model.cvm(grd.repeat(2, 1, 1, 1), sat, camera_k.repeat(2, 1, 1))
        image = torch.rand(1, 3, 98, 126, generator=gen).to(device)
        fast_feat = model.extractor(image)
        model.set_fast(False)
        slow_feat = model.extractor(image)
    assert torch.isfinite(fast_score).all() and torch.isfinite(slow_score).all()
    assert torch.equal(torch.isfinite(fast_raw), torch.isfinite(slow_raw)) and bool(keep.any())
    diff = float((fast_score - slow_score).abs().max())
    finite = torch.isfinite(slow_raw)
    raw_diff = float((fast_raw[finite] - slow_raw[finite]).abs().max())
    feat_diff = float((fast_feat - slow_feat).abs().max())
    print(f"real FG2 checkout, random weights: max |coupling fast - published| = {diff:.3g} (coupling up to "
          f"{float(slow_score.max()):.3g}; raw scores "
          f"{raw_diff:.3g}, {int(finite[0].any(0).sum())} of {finite.shape[2]} ground cells seen); DINOv2 SDPA vs "
          f"FG2's attention: max |feature difference| = {feat_diff:.3g} (features up to "
          f"{float(slow_feat.abs().max()):.3g})")
    assert diff <= 1e-4 * float(slow_score.max())  # relative to the largest coupling entry
    assert raw_diff <= 1e-5 * max(1.0, float(slow_raw[finite].abs().max()))
    rel = 1e-4 if model.extractor.amp_dtype == torch.float32 else 5e-3  # fp16 DINOv2 on CUDA: a few ulp
    assert feat_diff < rel * max(1.0, float(slow_feat.abs().max()))
