"""Fake FG2 checkout (tests only): a small randomly initialised `CVM` with FG2's constructor, forward signature
and outputs (dual-softmax coupling with a dustbin, raw scores -inf for ground cells no pixel sees). Not FG2's
network: ground BEV = pooled image features + learned queries, 1x1 projections, dot products. The `planted`
buffer ([on, angle rad, t_row m, t_col m]) replaces the coupling with exact correspondences
ground = R(angle) aerial + t of mass `planted_mass`, so tests can check the wrapper's frames."""

import ast
import configparser

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from models.modules import DinoExtractor  # noqa: F401  (FG2 imports its modules the same way)
from utils.utils import desc_l2norm

config = configparser.ConfigParser()
config.read("./config.ini")
kitti_grd_size = ast.literal_eval(config.get("KITTI", "ground_image_size"))


class CVM(nn.Module):
    def __init__(self, device, grd_bev_res, grd_height_res, sat_bev_res, grid_size_h, grid_size_v, temperature=0.1,
                 embed_dim=1024, desc_dim=128):
        super().__init__()
        self.device, self.temperature, self.embed_dim = device, temperature, embed_dim
        self.rows, self.cols = grd_bev_res // 2 + 1, grd_bev_res
        self.sat_bev_res, self.grid_size_h = sat_bev_res, grid_size_h
        self.dustbin_score = nn.Parameter(torch.tensor(1.0))
        # as FG2: .to(device) unregisters the parameter when device is CUDA
        queries = torch.rand(self.rows, self.cols, embed_dim)
        self.grd_grid_queries = nn.Parameter(data=queries, requires_grad=True).to(device)
        self.grd_projector = nn.Conv2d(embed_dim, desc_dim, 1)
        self.sat_projector = nn.Conv2d(embed_dim, desc_dim, 1)
        x = np.linspace(-grid_size_h / 2, 0, self.rows)
        y = np.linspace(-grid_size_h / 2, grid_size_h / 2, self.cols)
        z = np.linspace(-grid_size_v / 2, grid_size_v / 2, grd_height_res)
        gx, gy, gz = np.meshgrid(x, y, z, indexing="ij")
        self.grid_3d = torch.tensor(np.stack([gy, -gz, -gx], -1).reshape(-1, 3), dtype=torch.float32).to(device)
        self.heights = grd_height_res
        self.register_buffer("planted", torch.zeros(4))
        self.register_buffer("planted_mass", torch.tensor(0.8))

    def forward(self, grd_feature, sat_feature, camera_k):
        bs = grd_feature.shape[0]
        grd = F.adaptive_avg_pool2d(grd_feature, (self.rows, self.cols)) + self.grd_grid_queries.permute(2, 0, 1)[None]
        grd_desc = desc_l2norm(self.grd_projector(grd)).flatten(2)
        sat = F.interpolate(sat_feature, (self.sat_bev_res, self.sat_bev_res), mode="bilinear")
        sat_desc = desc_l2norm(self.sat_projector(sat)).flatten(2)
        score = torch.matmul(sat_desc.transpose(1, 2), grd_desc) / self.temperature
        proj = camera_k @ self.grid_3d.T[None]
        u = proj[:, 0] / proj[:, 2] / kitti_grd_size[1]
        v = proj[:, 1] / proj[:, 2] / kitti_grd_size[0]
        keep = ((u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)).view(bs, self.rows * self.cols, self.heights).any(-1)
        score = score.masked_fill(~keep[:, None, :], -float("inf"))
        m, n = score.shape[1:]
        bins0, bins1 = self.dustbin_score.expand(bs, m, 1), self.dustbin_score.expand(bs, 1, n)
        alpha = self.dustbin_score.expand(bs, 1, 1)
        couplings = torch.cat([torch.cat([score, bins0], -1), torch.cat([bins1, alpha], -1)], 1)
        couplings = F.softmax(couplings, 1) * F.softmax(couplings, 2)
        matching = couplings[:, :-1, :-1]
        if self.planted[0] > 0:
            matching = self._planted(keep)
        return matching, score

    def _planted(self, keep):
        a, tr, tc = (float(v) for v in self.planted[1:])
        half, step = self.grid_size_h / 2, self.grid_size_h / (self.sat_bev_res - 1)
        rows = torch.linspace(-half, 0, self.rows)
        cols = torch.linspace(-half, half, self.cols)
        ground = torch.stack(torch.meshgrid(rows, cols, indexing="ij"), -1).reshape(-1, 2).double()
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
