"""Heading-up satellite crops resampled on the matcher's torch device (fg2.device_crops).

`SatelliteMap.crop` cuts each crop on the CPU (one cv2.warpAffine) and the matcher uploads the K uint8 crops.
`DeviceCropper.cut` instead resamples the K crops of a trigger on the device in ONE batched bilinear call
(torch.nn.functional.affine_grid + grid_sample, zeros outside the map) from a device-resident copy of the part
of the mosaic they read, with the same geometry as `crop` (`SatelliteMap.crop_plan`: pyramid level, affine, the
box read) and the same off-map rules:

- the source: a pyramid level of an in-memory mosaic (`SatelliteMap.level_rgba`) whose RGBA size is at most
  `max_mosaic_mb` (default 512 MB) is uploaded ONCE and kept on the device (one level of one map at a time;
  on a CPU device it is a zero-copy view of the map's array); otherwise each trigger uploads one padded window,
  the union of the boxes its crops read, or one window per crop when that union exceeds `window_max_px`
  (default 4 M px: centres far apart). Device memory is thus bounded by max_mosaic_mb plus, per trigger, the
  window (<= window_max_px x 4 B uint8 and x 16 B float32) and the K x 4 x S x S float32 samples;
- a crop whose box is wholly outside the level is off the map (valid fraction 0); otherwise the alpha channel
  (255 on valid mosaic pixels, 0 outside or on nodata) is warped with the colours and the valid fraction is
  its mean / 255, 1 without looking when the box is inside and the mosaic has no mask; below min_valid (or 0)
  the crop is OffMapError with the message `crop` gives; pixels with alpha < 128 are zeroed;
- the samples are rounded and clamped to [0, 255] as the uint8 CPU crop is, then scaled to [0, 1] float32.

The warp is fp32 whatever the matcher's precision. Differences from `crop`: cv2 quantises the sample positions
to 1/32 px and the weights to 15 bits, grid_sample does not: within ~1 grey level on average, a few at sharp
edges (tests/test_device_crops.py asserts the bounds), and a valid fraction within ~1e-3 of `crop`'s.
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np
import torch
from torch.nn import functional as F

from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.satellite import CropPlan, SatelliteMap
from taco_mav.errors import OffMapError

__all__ = ["DeviceCropper", "DeviceCrops", "GeometryMatcher"]

DEVICE_MOSAIC_MAX_MB = 512.0
WINDOW_MAX_PX = 4_000_000


@dataclass(frozen=True)
class DeviceCrops:
    """The crops of one trigger on the device. images: (n, 3, S, S) float32 in [0, 1], the on-map crops in
    request order; present: per requested centre, whether its crop is in images; valid_fraction: per requested
    centre (0 when wholly off the map); errors: per requested centre, its OffMapError or None; centres_utm:
    (K, 2) absolute UTM E, N metres; heading: ENU rad; m_per_px; size_px."""

    images: torch.Tensor
    present: list[bool]
    valid_fraction: list[float]
    errors: list[OffMapError | None]
    centres_utm: np.ndarray
    heading: float
    m_per_px: float
    size_px: int


@runtime_checkable
class GeometryMatcher(Protocol):
    """The optional capability of a `Matcher` that resamples its crops itself (FG2): it is handed the map and
    the crop geometry instead of ready crops. Callers use it when `device_crops` is true (the profile switch);
    otherwise they call `match(frame, crops)` as for any matcher."""

    device_crops: bool

    def cut_crops(self, sat_map: SatelliteMap, centres_utm: np.ndarray, heading: float, size_px: int,
                  m_per_px: float) -> DeviceCrops:
        """The K crops centred on centres_utm (K, 2), heading-up, off-map ones flagged."""
        ...

    def match_crops(self, frame: GroundFrame, crops: DeviceCrops) -> list[MatchResult]:
        """One MatchResult per present crop, in order."""
        ...


def _theta(plan: CropPlan, size_px: int, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """affine_grid's 2x3 theta (align_corners=False) for a crop read from the window [x0, x0 + w) x [y0, y0 + h)
    of its level: normalised crop coordinates -> crop pixels -> level pixels (plan.M) -> normalised window."""
    S = float(size_px)
    out = np.array([[S / 2, 0.0, (S - 1) / 2], [0.0, S / 2, (S - 1) / 2], [0.0, 0.0, 1.0]])
    M = np.vstack([plan.M, [0.0, 0.0, 1.0]])
    M[0, 2] -= x0
    M[1, 2] -= y0
    norm = np.array([[2.0 / w, 0.0, 1.0 / w - 1.0], [0.0, 2.0 / h, 1.0 / h - 1.0]])
    return norm @ M @ out


class DeviceCropper:
    """Cuts heading-up crops on `device` (see the module docstring). Thread-safe."""

    def __init__(self, device: torch.device | str, max_mosaic_mb: float = DEVICE_MOSAIC_MAX_MB,
                 window_max_px: int = WINDOW_MAX_PX) -> None:
        self.device = torch.device(device)
        self.max_mosaic_mb = float(max_mosaic_mb)
        self.window_max_px = int(window_max_px)
        self._lock = threading.Lock()
        self._cached: tuple[weakref.ref[np.ndarray], torch.Tensor] | None = None
        self.uploads = 0  # host -> device copies of mosaic pixels (whole levels and windows), for tests

    def _level_on_device(self, sat_map: SatelliteMap, level: int) -> torch.Tensor | None:
        """The whole level on the device when the map holds it in memory and it is small enough, else None."""
        arr = sat_map.level_rgba(level)
        if arr is None or arr.nbytes > self.max_mosaic_mb * 1e6:
            return None
        with self._lock:
            if self._cached is not None and self._cached[0]() is arr:
                return self._cached[1]
            self._cached = None  # release the previous level before the next one is uploaded
            tensor = torch.from_numpy(arr).to(self.device)
            self.uploads += 1
            self._cached = (weakref.ref(arr), tensor)
            return tensor

    def _window(self, sat_map: SatelliteMap, source: torch.Tensor | None, level: int, x0: int, y0: int, x1: int,
                y1: int) -> torch.Tensor:
        """(h, w, 4) uint8 RGBA of [x0, x1) x [y0, y1) of the level, on the device."""
        if source is not None:
            return source[y0:y1, x0:x1]
        self.uploads += 1
        return torch.from_numpy(np.ascontiguousarray(sat_map.window_rgba(level, x0, y0, x1, y1))).to(self.device)

    def cut(self, sat_map: SatelliteMap, centres_utm: np.ndarray | Sequence[Sequence[float]], heading: float,
            size_px: int, m_per_px: float, min_valid: float | None = None) -> DeviceCrops:
        """The crops `sat_map.crop(c, heading, size_px, m_per_px, min_valid)` would give for each centre c
        (absolute UTM E, N metres), as one device batch; off-map ones are flagged instead of raised. MapError
        (as `crop`) for a non-finite centre or heading."""
        min_valid = sat_map.min_valid if min_valid is None else float(min_valid)
        centres = np.asarray(centres_utm, dtype=float).reshape(-1, 2)
        S, K = int(size_px), len(centres)
        plans = [sat_map.crop_plan(c, heading, S, m_per_px) for c in centres]
        errors: list[OffMapError | None] = [None] * K
        valid = [0.0] * K
        live = []
        for i, plan in enumerate(plans):
            if plan.wholly_off:
                errors[i] = sat_map.off_map_error(centres[i, 0], centres[i, 1], 0.0, min_valid, wholly=True)
            else:
                live.append(i)
        images = torch.zeros((0, 3, S, S), dtype=torch.float32, device=self.device)
        if live:
            samples = self._sample(sat_map, [plans[i] for i in live], S)  # (L, C, S, S) in [0, 255]
            if samples.shape[1] == 4:
                alpha = samples[:, 3]
                fractions = (alpha.mean(dim=(1, 2)) / 255.0).cpu().numpy()  # the one device -> host sync
                rgb = samples[:, :3] * (alpha >= 128)[:, None]
            else:  # every box inside a maskless mosaic
                fractions, rgb = np.ones(len(live)), samples
            keep = []
            for j, i in enumerate(live):
                valid[i] = 1.0 if plans[i].inside else float(fractions[j])
                if valid[i] < min_valid or valid[i] <= 0.0:
                    errors[i] = sat_map.off_map_error(centres[i, 0], centres[i, 1], valid[i], min_valid)
                else:
                    keep.append(j)
            if len(keep) < len(live):
                rgb = rgb[torch.as_tensor(keep, dtype=torch.long, device=self.device)]
            images = rgb / 255.0
        return DeviceCrops(images, [e is None for e in errors], valid, errors, centres, float(heading),
                           float(m_per_px), S)

    def _sample(self, sat_map: SatelliteMap, plans: list[CropPlan], S: int) -> torch.Tensor:
        """Bilinear samples (L, C, S, S) float32, rounded and clamped to [0, 255]; C = 3 when every box is
        inside a maskless mosaic (alpha is 255 throughout), else 4 (RGBA)."""
        level = plans[0].level
        H, W = plans[0].level_shape
        channels = 3 if all(p.inside for p in plans) else 4
        source = self._level_on_device(sat_map, level)
        boxes = np.array([p.bbox for p in plans])
        union = (max(boxes[:, 0].min(), 0), max(boxes[:, 1].min(), 0), min(boxes[:, 2].max(), W),
                 min(boxes[:, 3].max(), H))
        if (union[2] - union[0]) * (union[3] - union[1]) <= self.window_max_px:
            groups = [(list(range(len(plans))), union)]
        else:  # centres far apart: one window per crop
            groups = [([j], (max(b[0], 0), max(b[1], 0), min(b[2], W), min(b[3], H))) for j, b in enumerate(boxes)]
        parts = []
        for members, (x0, y0, x1, y1) in groups:
            window = self._window(sat_map, source, level, int(x0), int(y0), int(x1), int(y1))
            image = window[:, :, :channels].permute(2, 0, 1)[None].float()  # (1, C, h, w)
            h, w = image.shape[2], image.shape[3]
            theta = np.stack([_theta(plans[j], S, int(x0), int(y0), w, h) for j in members])
            theta_t = torch.as_tensor(theta, dtype=torch.float32, device=self.device)
            grid = F.affine_grid(theta_t, [len(members), channels, S, S], align_corners=False)
            # all crops of the group in ONE grid_sample call: their grids stacked along the rows
            out = F.grid_sample(image, grid.reshape(1, len(members) * S, S, 2), mode="bilinear",
                                padding_mode="zeros", align_corners=False)
            parts.append(out.view(channels, len(members), S, S).transpose(0, 1))
        samples = parts[0] if len(parts) == 1 else torch.cat(parts)
        return samples.round_().clamp_(0.0, 255.0)
