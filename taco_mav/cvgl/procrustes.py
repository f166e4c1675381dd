"""Weighted 2-D Procrustes (rigid, no scale) in closed form, batched, for the cross-view models' pose step.

Given point pairs (p_n, q_n) with weights w_n >= 0, find the rotation R (det +1) and translation t minimising
sum_n w_n |R p_n + t - q_n|^2. In 2-D the optimal angle is atan2(sum w (p' x q'), sum w (p' . q')) with p', q'
the points relative to their weighted means; t = q_mean - R p_mean. Units are whatever the points are in; the
angle is CCW in the points' own axes (for image-like (x right, y down) axes that is clockwise on screen).
"""

from __future__ import annotations

import torch

DEGENERATE = 1e-12  # a fit whose cross and dot sums are both below this (per unit weight) is not determined


def weighted_procrustes_2d(p: torch.Tensor, q: torch.Tensor,
                           w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """p, q: (B, N, 2) or (N, 2) (broadcast over the batch); w: (B, N). Returns R (B, 2, 2), t (B, 2) and ok (B,),
    False where the weights sum to zero or the points do not determine the rotation."""
    p, q, w = p.float(), q.float(), w.float().clamp_min(0.0)
    p, q = torch.broadcast_tensors(p, q) if p.dim() == q.dim() else (p.expand_as(q), q)
    wsum = w.sum(1, keepdim=True)
    safe = wsum.clamp_min(1e-30)
    p_bar = (w[..., None] * p).sum(1) / safe
    q_bar = (w[..., None] * q).sum(1) / safe
    pc, qc = p - p_bar[:, None], q - q_bar[:, None]
    cross = (w * (pc[..., 0] * qc[..., 1] - pc[..., 1] * qc[..., 0])).sum(1)
    dot = (w * (pc[..., 0] * qc[..., 0] + pc[..., 1] * qc[..., 1])).sum(1)
    ang = torch.atan2(cross, dot)
    c, s = torch.cos(ang), torch.sin(ang)
    R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    t = q_bar - (R @ p_bar[..., None])[..., 0]
    ok = (wsum[:, 0] > 0) & ((cross.abs() + dot.abs()) > DEGENERATE * safe[:, 0])
    return R, t, ok
