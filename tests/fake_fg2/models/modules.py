"""Fake FG2 checkout (tests only): FG2's `models/modules.py` at toy scale.

`self_attention_kitti` and `cross_attention_kitti` are FG2's code (vita-epfl/FG2 3239847) with the image's
feature-map shape read from config.ini instead of FG2's hard-coded (26, 88); `DinoExtractor` builds the tiny ViT
of `DINO_modules.dinov2` (DINOv2's attention code, one block) in fp16 as FG2 does; `DeepResBlock_desc` is a
small stand-in for FG2's descriptor head (convolutions, BatchNorm, L2 norm)."""

import ast
import configparser

import numpy as np
import torch
from DINO_modules.dinov2 import vit_large
from mmcv.ops.multi_scale_deform_attn import MultiScaleDeformableAttention
from torch import nn
from utils.utils import desc_l2norm

config = configparser.ConfigParser()
config.read("./config.ini")  # FG2's modules read the working directory's config.ini at import
kitti_grd_size = ast.literal_eval(config.get("KITTI", "ground_image_size"))
seed = config.getint("RandomSeed", "seed")
torch.manual_seed(seed)
torch.use_deterministic_algorithms(mode=True, warn_only=True)
EMBED_DIM = 32  # FG2: 1024 (DINOv2 ViT-L/14)


class DinoExtractor(nn.Module):
    """(B, 3, H, W) in [0, 1] -> (B, EMBED_DIM, H // 14, W // 14); dinov2_weights: the ViT's state_dict."""

    def __init__(self, dinov2_weights=None):
        super().__init__()
        if dinov2_weights is None:
            raise RuntimeError("the real DinoExtractor would download DINOv2 here")
        self.dino_channels, self.dino_downfactor = EMBED_DIM, 14
        self.amp_dtype = torch.float16
        self.dinov2_vitl14 = vit_large(img_size=518, patch_size=14, init_values=1.0, ffn_layer="mlp", block_chunks=0)
        self.dinov2_vitl14.load_state_dict(dinov2_weights)
        self.dinov2_vitl14.requires_grad_(False)
        self.dinov2_vitl14.eval()
        self.dinov2_vitl14.to(self.amp_dtype)

    def forward(self, x):
        B, C, H, W = x.shape
        d = self.dino_downfactor
        x = x[:, :, : d * (H // d), : d * (W // d)]
        with torch.no_grad():
            features = self.dinov2_vitl14.forward_features(x.to(self.amp_dtype))
            features = features["x_norm_patchtokens"].permute(0, 2, 1).reshape(
                B, self.dino_channels, H // d, W // d).float()
        return features


class DeepResBlock_desc(nn.Module):
    def __init__(self, bn, last_dim, in_channels, block_dims, add_posEnc, norm_desc, padding_mode="zeros"):
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, block_dims[0], 3, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(block_dims[0]) if bn else nn.Identity()
        self.conv2 = nn.Conv2d(block_dims[0], last_dim, 1)
        self.norm_desc = norm_desc

    def forward(self, feature_volume):
        x = self.conv2(torch.relu(self.bn1(self.conv1(feature_volume))))
        return desc_l2norm(x) if self.norm_desc else x


class self_attention_kitti(nn.Module):
    def __init__(self, device, num_horizontal, embed_dim=128):
        super(self_attention_kitti, self).__init__()
        self.device = device
        self.embed_dim = embed_dim
        self.num_horizontal = num_horizontal
        grd_row_self_ = np.linspace(0, 1, int(np.floor(self.num_horizontal / 2)) + 1)
        grd_col_self_ = np.linspace(0, 1, num_horizontal)
        grd_row_self, grd_col_self = np.meshgrid(grd_row_self_, grd_col_self_, indexing='ij')
        self.grd_reference_points = torch.stack((torch.tensor(grd_col_self), torch.tensor(grd_row_self)), -1).view(-1, 2).unsqueeze(1).to(torch.float).to(device)
        self.grd_spatial_shape = torch.tensor(([[int(np.floor(self.num_horizontal / 2)) + 1, num_horizontal]])).to(device).long()
        self.level_start_index = torch.tensor([0]).to(device)
        self.grd_attention_self = MultiScaleDeformableAttention(embed_dims=embed_dim, num_heads=8, num_levels=1, num_points=4,
                                                               batch_first=True)

    def forward(self, query):
        bs = query.size()[0]
        residual = query
        value = query
        grd_reference_points = self.grd_reference_points.unsqueeze(0).repeat(bs, 1, 1, 1)
        grd_bev = self.grd_attention_self(query=query, value=value, reference_points=grd_reference_points,
                                          spatial_shapes=self.grd_spatial_shape, level_start_index=self.level_start_index)
        return grd_bev + residual


class cross_attention_kitti(nn.Module):
    def __init__(self, device, num_horizontal, num_vertical, embed_dim, grid_size_h, grid_size_v):
        super(cross_attention_kitti, self).__init__()
        self.device = device
        self.embed_dim = embed_dim
        self.num_horizontal = num_horizontal
        self.num_vertical = num_vertical
        x_ = np.linspace(-grid_size_h / 2, 0, int(np.floor(self.num_horizontal / 2)) + 1)
        y_ = np.linspace(-grid_size_h / 2, grid_size_h / 2, num_horizontal)
        z_ = np.linspace(-grid_size_v / 2, grid_size_v / 2, num_vertical)
        grd_x, grd_y, grd_z = np.meshgrid(x_, y_, z_, indexing='ij')
        self.grid_3d = torch.stack([torch.tensor(grd_y), torch.tensor(-grd_z), torch.tensor(-grd_x)], dim=-1).reshape(-1, 3).to(torch.float).to(device)
        self.grd_spatial_shape_cross = torch.tensor(([[kitti_grd_size[0] // 14, kitti_grd_size[1] // 14]])).to(device).long()
        self.level_start_index = torch.tensor([0]).to(device)
        self.grd_attention_cross = MultiScaleDeformableAttention(embed_dims=embed_dim, num_heads=8, num_levels=1, num_points=4,
                                                                batch_first=True)
        self.projector = torch.nn.Linear(embed_dim, 1)

    def forward(self, query, value, camera_k):
        bs = query.size()[0]
        residual = query
        grid_3d = self.grid_3d.T.unsqueeze(0).repeat(bs, 1, 1)
        projected_points = camera_k @ grid_3d
        u = (projected_points[:, 0, :] / projected_points[:, 2, :] / kitti_grd_size[1]).view(bs, int(np.floor(self.num_horizontal / 2)) + 1, self.num_horizontal, self.num_vertical)
        v = (projected_points[:, 1, :] / projected_points[:, 2, :] / kitti_grd_size[0]).view(bs, int(np.floor(self.num_horizontal / 2)) + 1, self.num_horizontal, self.num_vertical)
        keep_index = torch.logical_and(torch.logical_and(u >= 0, u <= 1), torch.logical_and(v >= 0, v <= 1))
        keep_index = keep_index.sum(-1).to(torch.bool)
        grd_bev_list = []
        for i in range(self.num_vertical):
            grd_reference_points = torch.stack((u[:, :, :, i], v[:, :, :, i]), -1).view(bs, -1, 2).unsqueeze(2).to(torch.float)
            grd_bev = self.grd_attention_cross(query=query, value=value, reference_points=grd_reference_points,
                                               spatial_shapes=self.grd_spatial_shape_cross, level_start_index=self.level_start_index)
            grd_bev_list.append(grd_bev.view(bs, int(np.floor(self.num_horizontal / 2)) + 1, self.num_horizontal, self.embed_dim))
        grd_3d = torch.stack(grd_bev_list, dim=-1).permute(0, 1, 2, 4, 3)
        weights = torch.nn.functional.softmax(self.projector(grd_3d), dim=3)
        max_height_index = torch.argmax(weights, dim=3)
        grd_bev = (weights * grd_3d).sum(3)
        return grd_bev.view(bs, -1, self.embed_dim) + residual, max_height_index, keep_index
