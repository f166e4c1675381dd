"""Fake FG2 checkout (tests only): FG2's `CVM` (vita-epfl/FG2 models/model_kitti.py, 9b74e9b) at toy scale.

The constructor and `forward` are FG2's code (forward verbatim, including its use of grd_ffn1 in round 4);
the sizes are small (EMBED_DIM channels, a small descriptor head, see models/modules.py). The `planted` buffer
([on, angle rad, t_row m, t_col m]) replaces the coupling with exact correspondences ground = R(angle) aerial + t
of mass `planted_mass`, so tests can check the wrapper's frames."""

import configparser
import random

import numpy as np
import torch
import torch.nn as nn
from mmcv.cnn.bricks.transformer import FFN
from mmcv.ops.multi_scale_deform_attn import MultiScaleDeformableAttention  # noqa: F401
from models.modules import EMBED_DIM, DeepResBlock_desc
from models.modules import cross_attention_kitti as cross_attention
from models.modules import self_attention_kitti as self_attention
from torch.nn import functional as F

config = configparser.ConfigParser()
config.read("./config.ini")
eps = config.getfloat("Constants", "epsilon")
seed = config.getint("RandomSeed", "seed")
torch.manual_seed(seed)
np.random.seed(seed)
random.seed(seed)
torch.backends.cudnn.benchmark = False
torch.backends.cudnn.deterministic = True
torch.use_deterministic_algorithms(mode=True, warn_only=True)


class CVM(nn.Module):
    def __init__(self, device, grd_bev_res, grd_height_res, sat_bev_res, grid_size_h, grid_size_v, temperature=0.1,
                 embed_dim=EMBED_DIM, desc_dim=16):
        super(CVM, self).__init__()
        self.device = device
        self.temperature = temperature
        self.embed_dim = embed_dim
        self.grd_bev_res = grd_bev_res
        self.sat_bev_res = sat_bev_res
        self.grid_size_h = grid_size_h
        bn = True
        block_dims = [32, 16]
        self.dustbin_score = nn.Parameter(torch.tensor(1.))
        self.grd_grid_queries = nn.Parameter(data=torch.rand(int(np.floor(self.grd_bev_res/2))+1, grd_bev_res, embed_dim), requires_grad=True).to(device)
        for k in range(1, 7):
            setattr(self, f"grd_attention_self{k}", self_attention(device, grd_bev_res, embed_dim))
            setattr(self, f"grd_attention_cross{k}", cross_attention(device, grd_bev_res, grd_height_res, embed_dim, grid_size_h, grid_size_v))
        for k in range(1, 7):
            setattr(self, f"grd_ffn{k}", FFN(embed_dim))
        for k in range(1, 7):
            for j in range(1, 4):
                setattr(self, f"grd_layer_norm{k}{j}", nn.LayerNorm(embed_dim))
        self.grd_projector = DeepResBlock_desc(bn, last_dim=desc_dim, in_channels=embed_dim, block_dims=block_dims, add_posEnc=True, norm_desc=True)
        self.sat_projector = DeepResBlock_desc(bn, last_dim=desc_dim, in_channels=embed_dim, block_dims=block_dims, add_posEnc=True, norm_desc=True)
        self.register_buffer("planted", torch.zeros(4))
        self.register_buffer("planted_mass", torch.tensor(0.8))

    def forward(self, grd_feature, sat_feature, camera_k):

        bs = grd_feature.size()[0]

        grd_query = self.grd_grid_queries.view(-1, self.embed_dim).unsqueeze(0).repeat(bs, 1, 1)

        grd_value = grd_feature.permute(0,2,3,1).view(bs, -1, self.embed_dim).contiguous()

        # iter 1
        grd_query = self.grd_attention_self1(grd_query)
        grd_query = self.grd_layer_norm11(grd_query)

        grd_query, _, _ = self.grd_attention_cross1(grd_query, grd_value, camera_k)
        grd_query = self.grd_layer_norm12(grd_query)

        grd_query = self.grd_ffn1(grd_query)
        grd_query = self.grd_layer_norm13(grd_query)

        # iter 2
        grd_query = self.grd_attention_self2(grd_query)
        grd_query = self.grd_layer_norm21(grd_query)

        grd_query, _, _ = self.grd_attention_cross2(grd_query, grd_value, camera_k)
        grd_query = self.grd_layer_norm22(grd_query)

        grd_query = self.grd_ffn2(grd_query)
        grd_query = self.grd_layer_norm23(grd_query)

        # iter 3
        grd_query = self.grd_attention_self3(grd_query)
        grd_query = self.grd_layer_norm31(grd_query)

        grd_query, _, _ = self.grd_attention_cross3(grd_query, grd_value, camera_k)
        grd_query = self.grd_layer_norm32(grd_query)

        grd_query = self.grd_ffn3(grd_query)
        grd_query = self.grd_layer_norm33(grd_query)

        # iter 4
        grd_query = self.grd_attention_self4(grd_query)
        grd_query = self.grd_layer_norm41(grd_query)

        grd_query, _, _ = self.grd_attention_cross4(grd_query, grd_value, camera_k)
        grd_query = self.grd_layer_norm42(grd_query)

        grd_query = self.grd_ffn1(grd_query)
        grd_query = self.grd_layer_norm43(grd_query)

        # iter 5
        grd_query = self.grd_attention_self5(grd_query)
        grd_query = self.grd_layer_norm51(grd_query)

        grd_query, _, _ = self.grd_attention_cross5(grd_query, grd_value, camera_k)
        grd_query = self.grd_layer_norm52(grd_query)

        grd_query = self.grd_ffn5(grd_query)
        grd_query = self.grd_layer_norm53(grd_query)

        # iter 6
        grd_query = self.grd_attention_self6(grd_query)
        grd_query = self.grd_layer_norm61(grd_query)

        grd_query, height_index, grd_keep_index = self.grd_attention_cross6(grd_query, grd_value, camera_k)
        grd_query = self.grd_layer_norm62(grd_query)

        grd_query = self.grd_ffn6(grd_query)
        grd_query = self.grd_layer_norm63(grd_query)

        grd_query = grd_query.permute(0,2,1).view(bs, self.embed_dim, int(np.floor(self.grd_bev_res/2))+1, self.grd_bev_res)

        grd_desc = self.grd_projector(grd_query).flatten(2)

        sat_feature_bev = nn.functional.interpolate(sat_feature, (self.sat_bev_res, self.sat_bev_res), mode='bilinear')
        sat_desc = self.sat_projector(sat_feature_bev).flatten(2)

        matching_score_original = torch.matmul(sat_desc.transpose(1, 2).contiguous(), grd_desc) / self.temperature

        grd_keep_index = grd_keep_index.flatten(1)
        for b in range(bs):
            matching_score_original[b, :, ~grd_keep_index[b]] = -float('inf')

        bs, m, n = matching_score_original.shape

        bins0 = self.dustbin_score.expand(bs, m, 1)
        bins1 = self.dustbin_score.expand(bs, 1, n)
        alpha = self.dustbin_score.expand(bs, 1, 1)

        couplings = torch.cat([torch.cat([matching_score_original, bins0], -1),
                               torch.cat([bins1, alpha], -1)], 1)

        couplings = F.softmax(couplings, 1) * F.softmax(couplings, 2)
        matching_score = couplings[:, :-1, :-1]

        if self.planted[0] > 0:
            matching_score = self._planted(grd_keep_index)
        return matching_score, matching_score_original

    def _planted(self, keep):
        a, tr, tc = (float(v) for v in self.planted[1:])
        rows, cols = self.grd_bev_res // 2 + 1, self.grd_bev_res
        half, step = self.grid_size_h / 2, self.grid_size_h / (self.sat_bev_res - 1)
        ground = torch.stack(torch.meshgrid(torch.linspace(-half, 0, rows), torch.linspace(-half, half, cols),
                                            indexing="ij"), -1).reshape(-1, 2).double()
        c, s = np.cos(a), np.sin(a)
        R = torch.tensor([[c, -s], [s, c]], dtype=torch.float64)
        aerial = (ground - torch.tensor([tr, tc], dtype=torch.float64)) @ R  # R^T (ground - t), row vectors
        idx = torch.round((aerial + half) / step)
        exact = ((idx * step - half - aerial).abs() < 1e-3).all(1) & ((idx >= 0) & (idx < self.sat_bev_res)).all(1)
        out = torch.zeros(keep.shape[0], self.sat_bev_res ** 2, len(ground), device=keep.device)
        for j in torch.nonzero(exact)[:, 0].tolist():
            i = int(idx[j, 0]) * self.sat_bev_res + int(idx[j, 1])
            out[:, i, j] = self.planted_mass * keep[:, j]
        return out
