"""TinyFg2: a small FG2-shaped model (the `fg2.py` interface) for tests and plumbing checks, not for use.

Same structure as FG2 at toy scale: a conv encoder for each view, ground features lifted to BEV points with the
flat-ground homography, a soft-argmax correspondence of every BEV point over the aerial feature cells, and a
weighted 2-D Procrustes (closed-form angle) for the pose; the mass is the mean peak probability. Randomly
initialised from a seed; saved and loaded as {"format": "tiny_fg2", "dim": D, "seed": s, "state_dict": ...}.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import nn

from taco_mav.cvgl.procrustes import weighted_procrustes_2d
from taco_mav.errors import MatcherError

STRIDE = 8  # pixels per feature cell in both encoders


def _encoder(dim: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(3, 16, 5, stride=4, padding=2), nn.ReLU(), nn.Conv2d(16, dim, 3, stride=2, padding=1))


class TinyFg2(nn.Module):
    """dim: descriptor size; max_range_m: BEV points beyond this are dropped; temperature: softmax scale."""

    def __init__(self, dim: int = 16, max_range_m: float = 40.0, temperature: float = 0.1) -> None:
        super().__init__()
        self.dim, self.max_range_m, self.temperature = dim, max_range_m, temperature
        self.ground = _encoder(dim)
        self.aerial = _encoder(dim)

    def encode_ground(self, image: torch.Tensor, ground_from_pixel: torch.Tensor,
                      pixel_from_level: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(1, 3, H, W) -> BEV descriptors (N, D) and BEV points (N, 2) as (forward, left) metres (lifted through
        the flat-ground homography; pixel_from_level is not used)."""
        f = self.ground(image)[0]  # (D, h, w)
        _, h, w = f.shape
        v, u = torch.meshgrid(torch.arange(h, device=f.device), torch.arange(w, device=f.device), indexing="ij")
        uv1 = torch.stack([u * STRIDE + (STRIDE - 1) / 2, v * STRIDE + (STRIDE - 1) / 2, torch.ones_like(u)], -1)
        g = uv1.reshape(-1, 3).float() @ ground_from_pixel[0].float().T
        z = torch.where(g[:, 2].abs() < 1e-9, torch.full_like(g[:, 2], 1e-9), g[:, 2])
        pts = g[:, :2] / z[:, None]
        keep = (pts[:, 0] > 0.5) & (pts[:, 0] < self.max_range_m) & (pts[:, 1].abs() < self.max_range_m)
        desc = nn.functional.normalize(f.reshape(self.dim, -1).T.float(), dim=1)
        return desc[keep], pts[keep]

    def match_aerial(self, feats: tuple[torch.Tensor, torch.Tensor], aerial: torch.Tensor,
                     m_per_px: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Soft-argmax correspondences + weighted Procrustes: R_img (B, 2, 2), t_px (B, 2), mass (B,)."""
        desc, pts = feats
        B, _, S, _ = aerial.shape
        a = self.aerial(aerial).float()  # (B, D, h, w)
        _, _, h, w = a.shape
        a_desc = nn.functional.normalize(a.flatten(2), dim=1)  # (B, D, h*w)
        v, u = torch.meshgrid(torch.arange(h, device=a.device), torch.arange(w, device=a.device), indexing="ij")
        centre = (S - 1) / 2
        cells = torch.stack([u * STRIDE + (STRIDE - 1) / 2 - centre, v * STRIDE + (STRIDE - 1) / 2 - centre], -1)
        cells = cells.reshape(-1, 2).float()  # (h*w, 2) crop pixels from the centre
        if len(desc) == 0:
            return torch.eye(2).expand(B, 2, 2).clone(), torch.zeros(B, 2), torch.zeros(B)
        prob = torch.softmax(torch.einsum("nd,bdk->bnk", desc, a_desc) / self.temperature, dim=2)  # (B, N, K)
        q = prob @ cells  # (B, N, 2) expected aerial position of each BEV point
        wgt = prob.max(dim=2).values  # (B, N)
        p = torch.stack([-pts[:, 1], -pts[:, 0]], -1) / m_per_px  # BEV points in crop pixels (x right, y down)
        R, t, _ = weighted_procrustes_2d(p, q, wgt)
        return R, t, wgt.mean(1)


def save_tiny(path: Path, dim: int = 16, seed: int = 0) -> TinyFg2:
    """Build a seeded TinyFg2 and save it as a checkpoint file; returns the model."""
    torch.manual_seed(seed)
    model = TinyFg2(dim)
    torch.save({"format": "tiny_fg2", "dim": dim, "seed": seed, "state_dict": model.state_dict()}, path)
    return model


def build_model(checkout: Path, checkpoint: Path, device: Any) -> TinyFg2:
    """`fg2.entry` function: load a TinyFg2 checkpoint (MatcherError naming the file if it is not one)."""
    try:
        blob = torch.load(checkpoint, map_location=device, weights_only=True)
        if not isinstance(blob, dict) or blob.get("format") != "tiny_fg2":
            raise ValueError("not a tiny_fg2 checkpoint")
        model = TinyFg2(int(blob["dim"]))
        model.load_state_dict(blob["state_dict"])
    except Exception as exc:  # torch raises many types for corrupt files
        raise MatcherError(f"{checkpoint}: cannot load checkpoint ({type(exc).__name__}: {exc})") from None
    return model.to(device).eval()
