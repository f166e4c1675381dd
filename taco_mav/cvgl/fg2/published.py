"""`PublishedFg2`: the published FG2 KITTI model (vita-epfl/FG2) behind the `taco_mav.cvgl.fg2.adapter` interface.

FG2's frames (read from its `kitti_train_test.py` and `utils/utils.py`): the aerial image is a square of
`grid_size_h` metres (99 m for KITTI) fed at `satellite_image_size` px; both BEV point planes use metric (x, y)
= (row down, column right) coordinates, metres from the aerial centre / from the camera: the aerial grid is
`sat_bev_res`^2 points over [-G/2, G/2]^2, the ground grid (sat_bev_res // 2 + 1 rows over [-G/2, 0]) x
(grd_bev_res columns over [-G/2, G/2]), i.e. heading-up with the camera at the bottom centre. `CVM.forward(grd,
sat, camera_k)` returns `matching_score` (B, aerial points, ground points), a dual-softmax coupling with a
dustbin (every row and column sums to at most 1), and the raw scores (-inf for ground points no image pixel
sees). FG2 then samples `num_samples_matches` pairs from the coupling (multinomial) and fits a weighted
Procrustes ground = R aerial + t; its evaluation places the vehicle at -t in the aerial (row, col) frame and
reads the yaw from R.

This wrapper does the same with a generator seeded from FG2's `[RandomSeed] seed` on every call (deterministic),
and converts: vehicle (x right, y down) crop pixels = (-t_col, -t_row) / m_per_px; R_img (x, y axes) = the
inverse of R with the axes swapped; mass = the coupling mass within INLIER_M of the fitted pose, divided by the
number of ground points the camera sees (so in [0, 1]).

`fast` (default) replaces FG2's `CVM.forward` by `fast`'s equivalent (ground branch once per trigger, computed
in `encode_ground`; heights batched; SDPA in DINOv2); precisions: camera_k, crop resampling, CVM, pose and mass in
fp32 with autocast off; DINOv2 in FG2's fp16 on CUDA and fp32 elsewhere (`dinov2_precision_for`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import nn
from torch.nn import functional as F

from taco_mav.cvgl.fg2 import fast as fg2_fast
from taco_mav.cvgl.procrustes import weighted_procrustes_2d
from taco_mav.errors import MatcherError

log = logging.getLogger(__name__)

# A coupling pair supports the fitted pose when its residual is below this many metres (FG2's th_inlier in
# config.ini, 2.5; about one BEV cell at KITTI's 99 m / 40 cells).
INLIER_M = 2.5
# Crops may be this much smaller than FG2's aerial extent (grid_size_h) before they are refused.
EXTENT_TOLERANCE = 0.02
# Above this down-sampling factor the crop is area-smoothed (antialiased resize) before the exact resampling.
ANTIALIAS_ABOVE = 1.5


@dataclass(frozen=True)
class Fg2Settings:
    """FG2's KITTI settings, from the checkout's config.ini. grid_size_h/v: BEV extent and height span, metres;
    ground_size: (H, W) px of the ground image fed to DINOv2; aerial_size: side px of the aerial image;
    grd_bev_res, grd_height_res, sat_bev_res: BEV grid sizes; num_samples: pairs sampled for Procrustes; seed:
    FG2's random seed (construction and sampling)."""

    grid_size_h: float
    grid_size_v: float
    ground_size: tuple[int, int]
    aerial_size: int
    grd_bev_res: int
    grd_height_res: int
    sat_bev_res: int
    num_samples: int
    seed: int


def metric_grids(s: Fg2Settings) -> tuple[torch.Tensor, torch.Tensor]:
    """FG2's BEV point coordinates, metres, (row down, column right): aerial (sat_bev_res^2, 2) over the whole
    square, ground ((sat_bev_res // 2 + 1) * grd_bev_res, 2) over the half in front of the camera."""
    half = s.grid_size_h / 2
    sat = torch.linspace(-half, half, s.sat_bev_res, dtype=torch.float64)
    aerial = torch.stack(torch.meshgrid(sat, sat, indexing="ij"), -1).reshape(-1, 2)
    rows = torch.linspace(-half, 0.0, s.grd_bev_res // 2 + 1, dtype=torch.float64)
    cols = torch.linspace(-half, half, s.grd_bev_res, dtype=torch.float64)
    ground = torch.stack(torch.meshgrid(rows, cols, indexing="ij"), -1).reshape(-1, 2)
    return aerial.float(), ground.float()


def dinov2_precision_for(extractor: nn.Module, device: torch.device) -> torch.dtype:
    """FG2's DinoExtractor keeps DINOv2 in fp16 (its `amp_dtype`), right on CUDA; on other devices fp16 matmuls
    are emulated (about 100x slower than fp32 on a CPU without AVX512-FP16), so there DINOv2 runs in fp32.
    Returns the precision DINOv2 runs in."""
    vit = getattr(extractor, "dinov2_vitl14", None)
    if device.type == "cuda" or vit is None or not hasattr(extractor, "amp_dtype"):
        return getattr(extractor, "amp_dtype", torch.float32)
    vit.float()
    extractor.amp_dtype = torch.float32
    log.info("fg2: DINOv2 runs in fp32 on %s (FG2's fp16 is for CUDA)", device)
    return torch.float32


class GroundFeatures(NamedTuple):
    """What `PublishedFg2.encode_ground` hands to `match_aerial`. feature: DINOv2 features (1, 1024, h, w);
    camera_k (1, 3, 3) fp32; desc (1, D, N) and keep (1, N): the ground branch's output, computed once per
    trigger on the fast path (None on the published path, where FG2's CVM recomputes it per crop)."""

    feature: torch.Tensor
    camera_k: torch.Tensor
    desc: torch.Tensor | None = None
    keep: torch.Tensor | None = None


class PublishedFg2(nn.Module):
    """extractor: FG2's `DinoExtractor` (images -> DINOv2 patch features); cvm: FG2's `CVM`; settings: its
    config; fast: the fast path (`fast.py`: ground branch once per trigger, heights batched, SDPA in DINOv2)
    instead of FG2's own `CVM.forward` per crop; same outputs within float tolerance. Implements
    `encode_ground` / `match_aerial` of `taco_mav.cvgl.fg2.adapter`."""

    def __init__(self, extractor: nn.Module, cvm: nn.Module, settings: Fg2Settings, fast: bool = True) -> None:
        super().__init__()
        self.extractor, self.cvm, self.settings = extractor, cvm, settings
        aerial, ground = metric_grids(settings)
        self.register_buffer("aerial_xy", aerial, persistent=False)
        self.register_buffer("ground_xy", ground, persistent=False)
        self.fast = False
        self.set_fast(fast)

    def set_fast(self, fast: bool) -> None:
        """Switch between the fast path and FG2's published forward (both on the same weights)."""
        if fast:
            n = fg2_fast.use_sdpa(self.extractor)
            log.debug("fg2: fast path, %d DINOv2 attention blocks on SDPA", n)
        else:
            fg2_fast.restore_attention(self.extractor)
        self.fast = bool(fast)

    def compile_parts(self) -> None:
        """torch.compile DINOv2's forward_features (the bulk of the time after the fast path); one graph per
        input shape (ground image, batch of crops), compiled on first use."""
        vit = getattr(self.extractor, "dinov2_vitl14", None)
        if vit is None:
            raise MatcherError("fg2.compile: FG2's DinoExtractor has no dinov2_vitl14 to compile")
        vit.forward_features = torch.compile(vit.forward_features, dynamic=False)
        log.info("fg2: DINOv2 forward_features compiled with torch.compile (first triggers are slow)")

    def encode_ground(self, image: torch.Tensor, ground_from_pixel: torch.Tensor,
                      pixel_from_level: torch.Tensor) -> GroundFeatures:
        """(1, 3, H, W) in [0, 1] -> DINOv2 features of the image resized to FG2's ground size and camera_k for
        that size (1, 3, 3), fp32 whatever the caller's autocast; on the fast path also the ground branch. As
        FG2's KITTI loader: plain resize, intrinsics rows scaled, no normalisation."""
        gh, gw = self.settings.ground_size
        _, _, h, w = image.shape
        with torch.autocast(device_type=image.device.type, enabled=False):
            resized = F.interpolate(image.float(), size=(gh, gw), mode="bilinear", align_corners=False,
                                    antialias=True)
            scale = torch.diag(torch.tensor([gw / w, gh / h, 1.0], device=image.device))
            camera_k = scale @ pixel_from_level.float()
        feature = self.extractor(resized)  # FG2's DinoExtractor: fp16 on CUDA (fp32 elsewhere), fp32 out
        if not self.fast:
            return GroundFeatures(feature, camera_k)
        with torch.autocast(device_type=image.device.type, enabled=False):  # the CVM runs in fp32
            desc, keep = fg2_fast.ground_branch(self.cvm, feature.float(), camera_k, self.settings.ground_size)
        return GroundFeatures(feature, camera_k, desc, keep)

    def aerial_input(self, aerial: torch.Tensor, m_per_px: float) -> torch.Tensor:
        """(B, 3, S, S) crops at m_per_px -> (B, 3, A, A): the central grid_size_h metres, resampled to FG2's
        aerial size with the crop centre kept at the image centre. MatcherError if the crops are too small."""
        s = self.settings
        S = aerial.shape[-1]
        extent = S * m_per_px
        if extent < s.grid_size_h * (1.0 - EXTENT_TOLERANCE):
            raise MatcherError(f"fg2: crops cover {extent:.1f} m but FG2 (config.ini [KITTI] grid_size_h) needs "
                               f"{s.grid_size_h:g} m; raise map.crop_size_px x map.crop_m_per_px to at least that")
        keep = s.grid_size_h / extent  # share of the crop side FG2 sees
        aerial = aerial.float()
        if S * keep / s.aerial_size > ANTIALIAS_ABOVE:
            side = max(s.aerial_size, int(round(s.aerial_size / keep)))
            aerial = F.interpolate(aerial, size=(side, side), mode="bilinear", align_corners=False, antialias=True)
        theta = torch.tensor([[keep, 0.0, 0.0], [0.0, keep, 0.0]], device=aerial.device).expand(len(aerial), 2, 3)
        grid = F.affine_grid(theta, [len(aerial), 3, s.aerial_size, s.aerial_size], align_corners=False)
        return F.grid_sample(aerial, grid, mode="bilinear", padding_mode="zeros", align_corners=False)

    def match_aerial(self, feats: GroundFeatures, aerial: torch.Tensor,
                     m_per_px: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """FG2 on a batch of crops: R_img (B, 2, 2), t_px (B, 2) crop pixels (x right, y down) from the centre,
        mass (B,) in [0, 1]; NaN pose where the coupling is empty or degenerate."""
        B = len(aerial)
        with torch.autocast(device_type=aerial.device.type, enabled=False):
            sat_input = self.aerial_input(aerial, m_per_px)
        sat_feature = self.extractor(sat_input)  # FG2's DinoExtractor: fp16 on CUDA (fp32 elsewhere), fp32 out
        with torch.autocast(device_type=aerial.device.type, enabled=False):  # CVM, pose and mass in fp32
            if feats.desc is not None and feats.keep is not None:
                sat_desc = fg2_fast.aerial_descriptors(self.cvm, sat_feature.float())
                score, raw = fg2_fast.coupling(self.cvm, sat_desc, feats.desc, feats.keep)
            else:  # FG2's own forward, its ground branch once per crop
                score, raw = self.cvm(feats.feature.float().repeat(B, 1, 1, 1), sat_feature.float(),
                                      feats.camera_k.float().repeat(B, 1, 1))
            R, t, ok = self._fit(score.float())
            mass = self._inlier_mass(score.float(), raw, R, t)
        nan = torch.full_like(t, float("nan"))
        t_px = torch.where(ok[:, None], torch.stack([-t[:, 1], -t[:, 0]], -1) / m_per_px, nan)
        R_img = R.transpose(1, 2)[:, [1, 0]][:, :, [1, 0]]  # inverse rotation, axes (row, col) -> (x, y)
        return R_img, t_px, torch.where(ok, mass, torch.zeros_like(mass))

    def _fit(self, score: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """FG2's pose step: sample pairs from each coupling, weighted Procrustes ground = R aerial + t (metres)."""
        B, _, n_ground = score.shape
        gen = torch.Generator(device=score.device).manual_seed(self.settings.seed)
        flat = score.flatten(1).clamp_min(0.0)
        R = torch.eye(2, device=score.device).repeat(B, 1, 1)
        t = torch.zeros(B, 2, device=score.device)
        ok = torch.zeros(B, dtype=torch.bool, device=score.device)
        for b in range(B):  # per crop: an empty coupling voids only its own answer
            k = min(self.settings.num_samples, int((flat[b] > 0).sum()))
            if k < 2:
                log.warning("fg2: crop %d has an empty matching coupling", b)
                continue
            idx = torch.multinomial(flat[b], k, replacement=False, generator=gen)
            p = self.aerial_xy[torch.div(idx, n_ground, rounding_mode="trunc")]
            q = self.ground_xy[idx % n_ground]
            Rb, tb, okb = weighted_procrustes_2d(p[None], q[None], flat[b, idx][None])
            R[b], t[b], ok[b] = Rb[0], tb[0], okb[0]
        return R, t, ok

    def _inlier_mass(self, score: torch.Tensor, raw: torch.Tensor, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Coupling mass of pairs within INLIER_M of the pose, over the number of ground points seen (<= 1)."""
        mapped = self.aerial_xy @ R.transpose(1, 2) + t[:, None]  # (B, M, 2) aerial points in the ground frame
        resid = torch.cdist(mapped, self.ground_xy.expand(len(score), -1, -1))  # (B, M, N)
        seen = torch.isfinite(raw).any(1).sum(1).clamp_min(1)
        return ((score * (resid < INLIER_M)).sum((1, 2)) / seen).clamp(0.0, 1.0)
