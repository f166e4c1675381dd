"""A pure-PyTorch stand-in for the two mmcv classes FG2 imports: on non-CUDA devices, and where mmcv is absent.

FG2's `models/model_kitti.py` and `models/modules.py` import `mmcv.ops.multi_scale_deform_attn.
MultiScaleDeformableAttention` and `mmcv.cnn.bricks.transformer.FFN`. The FG2 import scope
(`shim.fg2_import_scope`) puts this module's classes into sys.modules under those names while FG2 is imported
when the device is not CUDA, or when mmcv is not installed (mmcv 2.x has no wheels for recent torch releases; a
source build needs nvcc matching torch's CUDA). They are written after mmcv 2.x (open-mmlab/mmcv,
`mmcv/ops/multi_scale_deform_attn.py`, `mmcv/cnn/bricks/transformer.py`): the same constructor arguments,
submodule and parameter names (FG2's checkpoints load unchanged), the same initialisation and the same forward
maths, bilinear sampling with zeros outside the feature map, with ONE difference that is the reason to use it on
a CPU: mmcv's CUDA kernel skips sampling points whose coordinates are not finite (its range test is false for
NaN and inf), while mmcv's own non-CUDA path hands them to `grid_sample`, which returns NaN. FG2's KITTI
cross-attention projects its ground row at the camera (depth 0) to inf / NaN pixels, so on a CPU with mmcv the
whole coupling became NaN. Here non-finite coordinates are moved far outside the map: zero contribution, as on
CUDA. Only what FG2 uses is implemented: batch_first attention with 2-D reference points, ReLU FFN.
"""

from __future__ import annotations

import math
import sys
import types
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

# sys.modules names this stand-in provides (parents first).
MODULE_NAMES = ("mmcv", "mmcv.ops", "mmcv.ops.multi_scale_deform_attn", "mmcv.cnn", "mmcv.cnn.bricks",
                "mmcv.cnn.bricks.transformer")


# Normalised grid coordinate for sampling points with non-finite coordinates: far outside [-1, 1], so bilinear
# sampling with zero padding gives exactly 0 (finite, so no integer overflow in grid_sample's index maths).
OUTSIDE = -1.0e4


def multi_scale_deformable_attn_pytorch(value: torch.Tensor, value_spatial_shapes: torch.Tensor,
                                        sampling_locations: torch.Tensor,
                                        attention_weights: torch.Tensor) -> torch.Tensor:
    """mmcv's reference implementation. value (bs, num_keys, heads, dim); value_spatial_shapes (levels, 2) as
    (h, w); sampling_locations (bs, queries, heads, levels, points, 2) as (x, y) in [0, 1]; attention_weights
    (bs, queries, heads, levels, points). Returns (bs, queries, heads * dim)."""
    bs, _, num_heads, embed_dims = value.shape
    _, num_queries, num_heads, num_levels, num_points, _ = sampling_locations.shape
    shapes = [(int(h), int(w)) for h, w in value_spatial_shapes.tolist()]
    value_list = value.split([h * w for h, w in shapes], dim=1)
    # mmcv's CUDA kernel skips points with non-finite coordinates; grid_sample would return NaN for them
    sampling_grids = torch.nan_to_num(2 * sampling_locations - 1, nan=OUTSIDE, posinf=-OUTSIDE, neginf=OUTSIDE)
    sampled = []
    for level, (h, w) in enumerate(shapes):
        value_l = value_list[level].flatten(2).transpose(1, 2).reshape(bs * num_heads, embed_dims, h, w)
        grid_l = sampling_grids[:, :, :, level].transpose(1, 2).flatten(0, 1)
        sampled.append(F.grid_sample(value_l, grid_l, mode="bilinear", padding_mode="zeros", align_corners=False))
    attention_weights = attention_weights.transpose(1, 2).reshape(bs * num_heads, 1, num_queries,
                                                                  num_levels * num_points)
    output = (torch.stack(sampled, dim=-2).flatten(-2) * attention_weights).sum(-1)
    return output.view(bs, num_heads * embed_dims, num_queries).transpose(1, 2).contiguous()


class MultiScaleDeformableAttention(nn.Module):
    """mmcv's `MultiScaleDeformableAttention` (Deformable DETR), parameters sampling_offsets,
    attention_weights, value_proj, output_proj."""

    def __init__(self, embed_dims: int = 256, num_heads: int = 8, num_levels: int = 4, num_points: int = 4,
                 im2col_step: int = 64, dropout: float = 0.1, batch_first: bool = False, norm_cfg: Any = None,
                 init_cfg: Any = None, value_proj_ratio: float = 1.0) -> None:
        super().__init__()
        if embed_dims % num_heads != 0:
            raise ValueError(f"embed_dims must be divisible by num_heads, but got {embed_dims} and {num_heads}")
        self.norm_cfg = norm_cfg
        self.dropout = nn.Dropout(dropout)
        self.batch_first = batch_first
        self.im2col_step = im2col_step
        self.embed_dims, self.num_levels = embed_dims, num_levels
        self.num_heads, self.num_points = num_heads, num_points
        self.sampling_offsets = nn.Linear(embed_dims, num_heads * num_levels * num_points * 2)
        self.attention_weights = nn.Linear(embed_dims, num_heads * num_levels * num_points)
        value_proj_size = int(embed_dims * value_proj_ratio)
        self.value_proj = nn.Linear(embed_dims, value_proj_size)
        self.output_proj = nn.Linear(value_proj_size, embed_dims)
        self.init_weights()

    def init_weights(self) -> None:
        """mmcv's initialisation: offsets on a ring per head, uniform attention, Xavier projections."""
        nn.init.constant_(self.sampling_offsets.weight, 0.0)
        thetas = torch.arange(self.num_heads, dtype=torch.float32) * (2.0 * math.pi / self.num_heads)
        grid = torch.stack([thetas.cos(), thetas.sin()], -1)
        grid = (grid / grid.abs().max(-1, keepdim=True)[0]).view(self.num_heads, 1, 1, 2)
        grid = grid.repeat(1, self.num_levels, self.num_points, 1)
        for i in range(self.num_points):
            grid[:, :, i, :] *= i + 1
        self.sampling_offsets.bias.data = grid.view(-1)
        nn.init.constant_(self.attention_weights.weight, 0.0)
        nn.init.constant_(self.attention_weights.bias, 0.0)
        for lin in (self.value_proj, self.output_proj):
            nn.init.xavier_uniform_(lin.weight, gain=1)
            nn.init.constant_(lin.bias, 0.0)

    def forward(self, query: torch.Tensor, key: torch.Tensor | None = None, value: torch.Tensor | None = None,
                identity: torch.Tensor | None = None, query_pos: torch.Tensor | None = None,
                key_padding_mask: torch.Tensor | None = None, reference_points: torch.Tensor | None = None,
                spatial_shapes: torch.Tensor | None = None, level_start_index: torch.Tensor | None = None,
                **kwargs: Any) -> torch.Tensor:
        if value is None:
            value = query
        if identity is None:
            identity = query
        if query_pos is not None:
            query = query + query_pos
        if not self.batch_first:
            query, value = query.permute(1, 0, 2), value.permute(1, 0, 2)
        if reference_points is None or spatial_shapes is None or reference_points.shape[-1] != 2:
            raise ValueError("this mmcv stand-in supports 2-D reference points with spatial_shapes only")
        bs, num_query, _ = query.shape
        _, num_value, _ = value.shape
        value = self.value_proj(value)
        if key_padding_mask is not None:
            value = value.masked_fill(key_padding_mask[..., None], 0.0)
        value = value.view(bs, num_value, self.num_heads, -1)
        offsets = self.sampling_offsets(query).view(bs, num_query, self.num_heads, self.num_levels,
                                                    self.num_points, 2)
        weights = self.attention_weights(query).view(bs, num_query, self.num_heads,
                                                     self.num_levels * self.num_points).softmax(-1)
        weights = weights.view(bs, num_query, self.num_heads, self.num_levels, self.num_points)
        normalizer = torch.stack([spatial_shapes[..., 1], spatial_shapes[..., 0]], -1)
        locations = reference_points[:, :, None, :, None, :] + offsets / normalizer[None, None, None, :, None, :]
        output = self.output_proj(multi_scale_deformable_attn_pytorch(value, spatial_shapes, locations, weights))
        if not self.batch_first:
            output = output.permute(1, 0, 2)
        return self.dropout(output) + identity


class FFN(nn.Module):
    """mmcv's `FFN` with its defaults (ReLU, no layer scale): identity + Linear(ReLU(Linear(x)))."""

    def __init__(self, embed_dims: int = 256, feedforward_channels: int = 1024, num_fcs: int = 2,
                 act_cfg: Any = None, ffn_drop: float = 0.0, dropout_layer: Any = None, add_identity: bool = True,
                 init_cfg: Any = None, layer_scale_init_value: float = 0.0) -> None:
        super().__init__()
        if num_fcs < 2:
            raise ValueError(f"num_fcs should be no less than 2, got {num_fcs}")
        if act_cfg not in (None, {"type": "ReLU", "inplace": True}, {"type": "ReLU"}):
            raise ValueError(f"this mmcv stand-in supports ReLU only, got act_cfg={act_cfg}")
        if dropout_layer or layer_scale_init_value > 0:
            raise ValueError("this mmcv stand-in supports FFN without dropout_layer and layer scale only")
        self.embed_dims, self.feedforward_channels, self.num_fcs = embed_dims, feedforward_channels, num_fcs
        layers: list[nn.Module] = []
        in_channels = embed_dims
        for _ in range(num_fcs - 1):
            layers.append(nn.Sequential(nn.Linear(in_channels, feedforward_channels), nn.ReLU(inplace=True),
                                        nn.Dropout(ffn_drop)))
            in_channels = feedforward_channels
        layers.append(nn.Linear(feedforward_channels, embed_dims))
        layers.append(nn.Dropout(ffn_drop))
        self.layers = nn.Sequential(*layers)
        self.dropout_layer = nn.Identity()
        self.add_identity = add_identity
        self.gamma2 = nn.Identity()

    def forward(self, x: torch.Tensor, identity: torch.Tensor | None = None) -> torch.Tensor:
        out = self.gamma2(self.layers(x))
        if not self.add_identity:
            return self.dropout_layer(out)
        return (x if identity is None else identity) + self.dropout_layer(out)


def stand_in_modules() -> dict[str, types.ModuleType]:
    """Module objects for MODULE_NAMES, ready to be put into sys.modules."""
    mods = {name: types.ModuleType(name, "taco_mav's stand-in for mmcv (taco_mav.cvgl.fg2.mmcv)")
            for name in MODULE_NAMES}
    for name in MODULE_NAMES:
        mods[name].__path__ = []  # a package, so submodules resolve through sys.modules
        parent, _, child = name.rpartition(".")
        if parent:
            setattr(mods[parent], child, mods[name])
    mods["mmcv"].__version__ = "0.0.0+taco_mav_stand_in"
    ops = mods["mmcv.ops.multi_scale_deform_attn"]
    ops.MultiScaleDeformableAttention = MultiScaleDeformableAttention
    ops.multi_scale_deformable_attn_pytorch = multi_scale_deformable_attn_pytorch
    mods["mmcv.ops"].MultiScaleDeformableAttention = MultiScaleDeformableAttention
    mods["mmcv.cnn.bricks.transformer"].FFN = FFN
    return mods


def mmcv_installed() -> bool:
    """True when a real mmcv is importable (then CUDA models use it)."""
    if "mmcv" in sys.modules:
        return getattr(sys.modules["mmcv"], "__version__", "") != "0.0.0+taco_mav_stand_in"
    import importlib.util

    return importlib.util.find_spec("mmcv") is not None
