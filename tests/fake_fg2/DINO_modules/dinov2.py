"""Fake FG2 checkout (tests only): a one-block ViT with DINOv2's layout (patch_embed, cls_token, pos_embed,
blocks of norm / attention / LayerScale / MLP, final norm; DINOv2's hand-written `Attention` in
`DINO_modules/layers.py`), at EMBED_DIM channels instead of ViT-L's 1024."""

import torch
from torch import nn

from DINO_modules.layers import Block

EMBED_DIM = 32


class TinyViT(nn.Module):
    def __init__(self, patch_size=14, init_values=1.0, **kwargs):
        super().__init__()
        self.patch_embed = nn.Conv2d(3, EMBED_DIM, patch_size, stride=patch_size)
        self.cls_token = nn.Parameter(torch.randn(1, 1, EMBED_DIM) * 0.02)
        self.blocks = nn.ModuleList([Block(EMBED_DIM, 4, init_values)])
        self.norm = nn.LayerNorm(EMBED_DIM, eps=1e-6)
        nn.init.normal_(self.patch_embed.weight, std=0.2)

    def forward_features(self, x):
        B = x.shape[0]
        tokens = self.patch_embed(x).flatten(2).transpose(1, 2)
        # positions: a fixed sinusoid of the token index (DINOv2 interpolates a learned table)
        n = torch.arange(tokens.shape[1], device=x.device, dtype=torch.float32)[:, None]
        freq = torch.arange(EMBED_DIM, device=x.device, dtype=torch.float32)[None] / EMBED_DIM
        tokens = tokens + torch.sin(n * 0.37 * (1 + freq) + freq).to(tokens.dtype)
        x = torch.cat([self.cls_token.expand(B, -1, -1).to(tokens.dtype), tokens], 1)
        for blk in self.blocks:
            x = blk(x)
        x = self.norm(x)
        return {"x_norm_clstoken": x[:, 0], "x_norm_patchtokens": x[:, 1:]}


def vit_large(patch_size=16, **kwargs):
    return TinyViT(patch_size=patch_size, **kwargs)
