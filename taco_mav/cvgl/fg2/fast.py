"""The fast path of the published FG2 KITTI model: the same maths as FG2's `CVM.forward`, reorganised.

FG2's `CVM.forward(grd_feature, sat_feature, camera_k)` (models/model_kitti.py at commit 9b74e9b, modules.py at
3239847) runs its ground branch (learned BEV queries refined by six rounds of deformable self-attention,
deformable cross-attention into the ground image at `grd_height_res` heights, FFN, layer norms; then the
descriptor head) for every batch element, although for our five crops of one trigger the ground image and
camera_k are the same. Here:

- `ground_branch` runs it ONCE per trigger (batch 1) and returns the ground descriptors and the mask of ground
  cells the camera sees; `coupling` broadcasts them against the B crops' descriptors.
- `cross_attention` samples all heights of one round in ONE deformable-attention call (the queries repeated
  per height, each with its own reference points) instead of FG2's loop of `grd_height_res` calls; the
  attention is per query, so every output is the same.
- `use_sdpa` swaps DINOv2's hand-written attention (q @ k^T, softmax, @ v) for
  `torch.nn.functional.scaled_dot_product_attention` with the same weights; `restore_attention` undoes it.

Every function reads the checkout's modules and weights; nothing is copied. FG2's forward uses `grd_ffn1` in
its fourth round (its `grd_ffn4` is never used): reproduced in FFN_OF_ROUND. The equality with FG2's own
forward is a test (tests/test_fg2_fast.py) on the fake checkout and, where one is given, on the real one.
"""

from __future__ import annotations

import types
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

# Which grd_ffn<k> FG2's CVM.forward applies in rounds 1..6.
FFN_OF_ROUND = (1, 2, 3, 1, 5, 6)
# DINOv2 attention classes (DINO_modules/layers/attention.py) whose forward use_sdpa replaces.
DINO_ATTENTION_CLASSES = ("Attention", "MemEffAttention")


def ground_branch(cvm: nn.Module, grd_feature: torch.Tensor, camera_k: torch.Tensor,
                  ground_size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """FG2's ground branch for one image: grd_feature (1, 1024, h, w) DINOv2 features, camera_k (1, 3, 3) at
    ground_size (H, W) px. Returns the descriptors (1, D, N) and keep (1, N) bool, the ground cells that at least
    one height projects into the image (N = (grd_bev_res // 2 + 1) * grd_bev_res)."""
    bs = grd_feature.shape[0]
    query = cvm.grd_grid_queries.reshape(-1, cvm.embed_dim).unsqueeze(0).expand(bs, -1, -1)
    value = grd_feature.permute(0, 2, 3, 1).reshape(bs, -1, cvm.embed_dim).contiguous()
    keep = torch.ones(1, dtype=torch.bool, device=grd_feature.device)
    for k, ffn in enumerate(FFN_OF_ROUND, start=1):
        query = getattr(cvm, f"grd_attention_self{k}")(query)
        query = getattr(cvm, f"grd_layer_norm{k}1")(query)
        query, keep = cross_attention(getattr(cvm, f"grd_attention_cross{k}"), query, value, camera_k, ground_size)
        query = getattr(cvm, f"grd_layer_norm{k}2")(query)
        query = getattr(cvm, f"grd_ffn{ffn}")(query)
        query = getattr(cvm, f"grd_layer_norm{k}3")(query)
    rows = cvm.grd_bev_res // 2 + 1
    query = query.permute(0, 2, 1).reshape(bs, cvm.embed_dim, rows, cvm.grd_bev_res)
    return cvm.grd_projector(query).flatten(2), keep.flatten(1)


def cross_attention(block: nn.Module, query: torch.Tensor, value: torch.Tensor, camera_k: torch.Tensor,
                    ground_size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """FG2's `cross_attention_kitti.forward` with all heights in one deformable-attention call. query (bs, N,
    C), value (bs, h * w, C), camera_k (bs, 3, 3). Returns (bs, N, C) and keep (bs, rows, cols)."""
    bs, n, c = query.shape
    heights = block.num_vertical
    rows, cols = block.num_horizontal // 2 + 1, block.num_horizontal
    projected = camera_k @ block.grid_3d.T.unsqueeze(0)  # (bs, 3, rows * cols * heights)
    u = (projected[:, 0, :] / projected[:, 2, :] / ground_size[1]).view(bs, rows, cols, heights)
    v = (projected[:, 1, :] / projected[:, 2, :] / ground_size[0]).view(bs, rows, cols, heights)
    keep = ((u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)).any(-1)
    ref = torch.stack((u, v), -1).permute(0, 3, 1, 2, 4).reshape(bs, heights * n, 1, 2).float()
    out = block.grd_attention_cross(query=query.repeat(1, heights, 1), value=value, reference_points=ref,
                                    spatial_shapes=block.grd_spatial_shape_cross,
                                    level_start_index=block.level_start_index)
    grd_3d = out.view(bs, heights, rows, cols, c).permute(0, 2, 3, 1, 4)  # (bs, rows, cols, heights, C)
    weights = F.softmax(block.projector(grd_3d), dim=3)
    return (weights * grd_3d).sum(3).reshape(bs, -1, c) + query, keep


def aerial_descriptors(cvm: nn.Module, sat_feature: torch.Tensor) -> torch.Tensor:
    """FG2's aerial branch: sat_feature (B, 1024, h, w) -> descriptors (B, D, sat_bev_res^2)."""
    bev = F.interpolate(sat_feature, (cvm.sat_bev_res, cvm.sat_bev_res), mode="bilinear")
    return cvm.sat_projector(bev).flatten(2)


def coupling(cvm: nn.Module, sat_desc: torch.Tensor, grd_desc: torch.Tensor,
             keep: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """FG2's dual-softmax coupling with a dustbin for B crops against one ground: sat_desc (B, D, M), grd_desc
    (1, D, N), keep (1, N). Returns (matching_score, matching_score_original) as CVM.forward does, (B, M, N)."""
    score = torch.matmul(sat_desc.transpose(1, 2), grd_desc) / cvm.temperature
    score = score.masked_fill(~keep[:, None, :], -float("inf"))
    bs, m, n = score.shape
    bins0 = cvm.dustbin_score.expand(bs, m, 1)
    bins1 = cvm.dustbin_score.expand(bs, 1, n)
    alpha = cvm.dustbin_score.expand(bs, 1, 1)
    couplings = torch.cat([torch.cat([score, bins0], -1), torch.cat([bins1, alpha], -1)], 1)
    couplings = F.softmax(couplings, 1) * F.softmax(couplings, 2)
    return couplings[:, :-1, :-1], score


def _sdpa_forward(self: Any, x: torch.Tensor, attn_bias: Any = None) -> torch.Tensor:
    """DINOv2's `Attention.forward` through scaled_dot_product_attention (default scale 1/sqrt(head dim), which
    is DINOv2's `self.scale`; no dropout in eval)."""
    if attn_bias is not None:
        raise ValueError("fg2: DINOv2 attention with an attn_bias (nested tensors) is not supported")
    B, N, C = x.shape
    qkv = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
    out = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2], scale=self.scale)
    return self.proj_drop(self.proj(out.transpose(1, 2).reshape(B, N, C)))


def use_sdpa(module: nn.Module) -> int:
    """Route every DINOv2 attention block under `module` through SDPA; returns how many were routed."""
    count = 0
    for m in module.modules():
        if type(m).__name__ in DINO_ATTENTION_CLASSES and hasattr(m, "qkv") and hasattr(m, "proj"):
            m.forward = types.MethodType(_sdpa_forward, m)
            count += 1
    return count


def restore_attention(module: nn.Module) -> None:
    """Undo use_sdpa: DINOv2's own attention forward again."""
    for m in module.modules():
        if "forward" in vars(m):
            del m.forward
