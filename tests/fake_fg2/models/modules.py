"""Fake FG2 checkout (tests only): `DinoExtractor` with FG2's signature and output layout, a single random
14x14 patch convolution in place of DINOv2 ViT-L/14 (1024 channels, stride 14)."""

import configparser

import torch
from torch import nn

config = configparser.ConfigParser()
config.read("./config.ini")  # FG2's modules read the working directory's config.ini at import
seed = config.getint("RandomSeed", "seed")
torch.manual_seed(seed)
torch.use_deterministic_algorithms(mode=True, warn_only=True)


class DinoExtractor(nn.Module):
    """(B, 3, H, W) in [0, 1] -> (B, 1024, H // 14, W // 14); dinov2_weights: the backbone's state_dict."""

    def __init__(self, dinov2_weights=None):
        super().__init__()
        if dinov2_weights is None:
            raise RuntimeError("the real DinoExtractor would download DINOv2 here")
        self.dino_channels, self.dino_downfactor = 1024, 14
        self.dinov2_vitl14 = nn.Conv2d(3, self.dino_channels, self.dino_downfactor, stride=self.dino_downfactor)
        nn.init.normal_(self.dinov2_vitl14.weight)  # consumes the RNG like the ViT's initialisation does
        self.dinov2_vitl14.load_state_dict(dinov2_weights)
        self.dinov2_vitl14.requires_grad_(False)
        self.dinov2_vitl14.eval()

    def forward(self, x):
        _, _, H, W = x.shape
        d = self.dino_downfactor
        with torch.no_grad():
            return self.dinov2_vitl14(x[:, :, : d * (H // d), : d * (W // d)].float())
