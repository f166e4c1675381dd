"""Fake FG2 checkout (tests only): a one-block ViT with DINOv2's layout (patch_embed, cls_token, pos_embed,
blocks of norm / attention / LayerScale / MLP, final norm) and DINOv2's hand-written `Attention`
(`DINO_modules/layers/attention.py`), at EMBED_DIM channels instead of ViT-L's 1024."""

import torch
from torch import nn

EMBED_DIM = 32


class Attention(nn.Module):
    def __init__(self, dim, num_heads=8, qkv_bias=False, proj_bias=True, attn_drop=0.0, proj_drop=0.0):
        super().__init__()
        self.num_heads = num_heads
        head_dim = dim // num_heads
        self.scale = head_dim**-0.5
        self.qkv = nn.Linear(dim, dim * 3, bias=qkv_bias)
        self.attn_drop = nn.Dropout(attn_drop)
        self.proj = nn.Linear(dim, dim, bias=proj_bias)
        self.proj_drop = nn.Dropout(proj_drop)

    def forward(self, x):
        B, N, C = x.shape
        qkv = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0] * self.scale, qkv[1], qkv[2]
        attn = q @ k.transpose(-2, -1)
        attn = attn.softmax(dim=-1)
        attn = self.attn_drop(attn)
        x = (attn @ v).transpose(1, 2).reshape(B, N, C)
        x = self.proj(x)
        x = self.proj_drop(x)
        return x


class MemEffAttention(Attention):
    def forward(self, x, attn_bias=None):
        assert attn_bias is None
        return super().forward(x)


class Block(nn.Module):
    def __init__(self, dim, num_heads, init_values):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = MemEffAttention(dim, num_heads=num_heads, qkv_bias=True)
        self.ls1 = nn.Parameter(init_values * torch.ones(dim))
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = nn.Sequential(nn.Linear(dim, 4 * dim), nn.GELU(), nn.Linear(4 * dim, dim))
        self.ls2 = nn.Parameter(init_values * torch.ones(dim))

    def forward(self, x):
        x = x + self.ls1 * self.attn(self.norm1(x))
        return x + self.ls2 * self.mlp(self.norm2(x))


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
