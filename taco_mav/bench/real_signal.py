"""Bench section: how much position signal a ground channel carries on the real pairs, before any matcher.

A matcher can only place a view where its evidence ranks the true position above the others. This section
measures that for the dense channels the classical matcher can describe (`grey_channel`: luma, unsaturated,
achromatic), raw or as gradient orientation (`describe`), with nothing else in the way: no rotation search, no
masks, no decoys, no answer check. For every place of every panorama set under the real-pairs folder
(`taco_mav.bench.real.default_root`), the panorama's ground between MIN_RANGE_M and MAX_RANGE_M is projected onto
a north-up bird's-eye view at the aerial's scale (`ground_bev`), all round (field of view 360) or in wedges of
FOV_DEG about seeded bearings (what a forward camera sees of the same ground), and compared with the aerial by
zero-normalised cross-correlation at every position within RADIUS_M of the truth, the heading exact. Pinhole sets
are skipped: their frames are not all round.

Keys, per channel, descriptor and field of view (`real_signal_<grey>_<descriptor>_fov<F>_`):
`truth_percentile` (median over the views of the share of searched positions that score below the truth: 0.5 is
chance, 1 the truth on top), `within_3m_share` (the best-scoring position within SUCCESS_M of the truth),
`median_error_m` (of the best-scoring position); `real_signal_chance_within_3m_share` is the share of the searched
square within SUCCESS_M of its centre, what a position drawn at random scores, and `real_signal_views` the views
per wedge set. Seeded: the same seed, the same figures.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from taco_mav.bench.real import default_root
from taco_mav.cvgl.descriptors import GREYS, describe, grey_channel
from taco_mav.datasets.real_pairs import RealSet, find_sets, ground_bev, read_rgb
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

SUCCESS_M = 3.0  # as taco_mav.bench.real
MIN_RANGE_M = 3.0  # nearer, the panorama sees the Street View car's roof, a rover its own body
MAX_RANGE_M = 16.0  # the near field: at 0.7 deg a row (CVACT) one row spans ~1.3 m of ground at 16 m, ~3 m at 25 m
RADIUS_M = 15.0  # searched positions: within this of the truth along each axis (twice the priors' 4-8 m)
FOV_DEG = (360.0, 90.0)  # all round, and a wide forward camera's wedge
WEDGE_BEARINGS_DEG = (0.0, 90.0, 180.0, 270.0)  # per place, turned by a seeded angle (as taco_mav.bench.real)
SIGNAL_DESCRIPTORS = ("grey", "orientation")  # "grey": the channel itself
ORIENTATION_SIGMA_M = 2.0  # the orientation descriptor's normalisation window (the profiles' classical.lcn_sigma_m)


@dataclass(frozen=True)
class Signal:
    """One view's verdict: where the truth ranks among the searched positions (share scoring below it), and the
    best-scoring position's distance from the truth, m."""

    truth_percentile: float
    error_m: float


def _channels(rgb: np.ndarray, grey: str, descriptor: str, mask: np.ndarray | None, m_per_px: float) -> np.ndarray:
    """The compared channels (C, H, W) float32 of an RGB image: the grey channel, or its orientation descriptor."""
    g = grey_channel(rgb, grey).astype(np.float32)
    if descriptor == "grey":
        return (g if mask is None else g * mask)[None]
    return describe("orientation", g, mask, max(ORIENTATION_SIGMA_M / m_per_px, 0.5))


def ncc_map(aerial: np.ndarray, template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Zero-normalised cross-correlation of the template's channels (C, h, w) under mask (h, w, 0/1) with the
    aerial's (C, H, W) at every placement wholly inside it: (H - h + 1, W - w + 1), placement (row, col) = the
    template's top-left pixel. The channels are normalised together (one mean each, one joint energy)."""
    n = float(mask.sum())
    num = np.zeros((aerial.shape[1] - template.shape[1] + 1, aerial.shape[2] - template.shape[2] + 1), np.float32)
    var = np.zeros_like(num)
    energy = 0.0
    for a, t in zip(aerial, template):
        t = t * mask
        t = t - mask * (t.sum() / n)
        energy += float((t * t).sum())
        num += cv2.matchTemplate(a, t, cv2.TM_CCORR)
        s1 = cv2.matchTemplate(a, mask, cv2.TM_CCORR)
        s2 = cv2.matchTemplate(a * a, mask, cv2.TM_CCORR)
        var += np.maximum(s2 - s1 * s1 / n, 0.0)
    return num / (np.sqrt(var * energy) + 1e-6)


@dataclass(frozen=True)
class PlaceGround:
    """One place as every view of it is scored: the panorama's ground from above (`ground_bev`, the camera on the
    template at (half, half) plus the truth's fraction of a pixel, so that the truth is a whole placement), each
    pixel's range (m) and compass bearing (deg), the aerial window the search covers, its scale (m/px) and the
    searched radius (px)."""

    bev: np.ndarray
    range_m: np.ndarray
    bearing_deg: np.ndarray
    window: np.ndarray
    m_per_px: float
    radius_px: int


def place_ground(pano: np.ndarray, aerial: np.ndarray, rset: RealSet, truth_px: tuple[float, float]) -> PlaceGround:
    """The ground of one place (PlaceGround); DataError when the aerial does not hold the ground and the search."""
    m = rset.m_per_px
    half = int(math.ceil(MAX_RANGE_M / m)) + 2
    size = 2 * half
    r_px = int(math.ceil(RADIUS_M / m))
    tx, ty = truth_px
    ix, iy = int(math.floor(tx)), int(math.floor(ty))
    top, left = iy - half - r_px, ix - half - r_px
    bottom, right = iy - half + r_px + size, ix - half + r_px + size
    if top < 0 or left < 0 or bottom > aerial.shape[0] or right > aerial.shape[1]:
        raise DataError(f"{rset.folder}: the aerial ({aerial.shape[1]} x {aerial.shape[0]} px) does not hold "
                        f"{MAX_RANGE_M:.0f} m of ground plus {RADIUS_M:.0f} m of search around truth_px {truth_px}")
    bev, rng, bearing = ground_bev(pano, rset.ground, rset.camera_height_m, m, size, (tx - ix, ty - iy))
    return PlaceGround(bev, rng, bearing, aerial[top:bottom, left:right], m, r_px)


def score(g: PlaceGround, grey: str, descriptor: str, fov_deg: float, bearing_deg: float) -> Signal:
    """The signal of one view of a place: a wedge of fov_deg about compass bearing_deg (360: all round)."""
    keep = (g.range_m >= MIN_RANGE_M) & (g.range_m <= MAX_RANGE_M)
    if fov_deg < 360.0:
        keep &= np.abs(np.mod(g.bearing_deg - bearing_deg + 180.0, 360.0) - 180.0) <= fov_deg / 2.0
    mask = keep.astype(np.float32)
    m, r = g.m_per_px, g.radius_px
    scores = ncc_map(_channels(g.window, grey, descriptor, None, m), _channels(g.bev, grey, descriptor, mask, m), mask)
    truth = float(scores[r, r])
    best = np.unravel_index(int(np.argmax(scores)), scores.shape)
    return Signal(float(np.mean(scores < truth)), math.hypot(best[0] - r, best[1] - r) * m)


def score_view(pano: np.ndarray, aerial: np.ndarray, rset: RealSet, truth_px: tuple[float, float], grey: str,
               descriptor: str, fov_deg: float, bearing_deg: float) -> Signal:
    """`score` of one view, the place's ground made for it (`place_ground`)."""
    return score(place_ground(pano, aerial, rset, truth_px), grey, descriptor, fov_deg, bearing_deg)


def evaluate(root: Path, seed: int = 0) -> dict[str, Any]:
    """The section's keys (module docstring) for every panorama set under root."""
    sets = [s for s in find_sets(root) if s.is_panorama]
    if not sets:
        raise DataError(f"{root}: no panorama set (the signal is measured all round)")
    rng = np.random.default_rng(seed)
    places = [(place_ground(read_rgb(pair.ground), read_rgb(pair.aerial), rset, pair.truth_px),
               float(rng.uniform(0.0, 90.0))) for rset in sets for pair in rset.pairs]
    keys: dict[str, Any] = {}
    for grey in GREYS:
        for descriptor in SIGNAL_DESCRIPTORS:
            for fov in FOV_DEG:
                bearings = (0.0,) if fov >= 360.0 else WEDGE_BEARINGS_DEG
                signals = [score(g, grey, descriptor, fov, b + turn) for g, turn in places for b in bearings]
                prefix = f"real_signal_{grey}_{descriptor}_fov{fov:.0f}"
                err = np.array([s.error_m for s in signals])
                keys[f"{prefix}_truth_percentile"] = float(np.median([s.truth_percentile for s in signals]))
                keys[f"{prefix}_within_3m_share"] = float(np.mean(err < SUCCESS_M))
                keys[f"{prefix}_median_error_m"] = float(np.median(err))
                keys[f"real_signal_views_fov{fov:.0f}"] = len(signals)
                log.info("%s: truth percentile %.2f, best within 3 m %.2f, median error %.1f m", prefix,
                         keys[f"{prefix}_truth_percentile"], keys[f"{prefix}_within_3m_share"],
                         keys[f"{prefix}_median_error_m"])
    m = min(s.m_per_px for s in sets)
    r_px = int(math.ceil(RADIUS_M / m))
    yy, xx = np.mgrid[-r_px:r_px + 1, -r_px:r_px + 1]
    keys["real_signal_chance_within_3m_share"] = float(np.mean(np.hypot(yy, xx) * m < SUCCESS_M))
    return keys


def run(progress: bool = False, real_pairs: str | Path | None = None) -> dict[str, Any]:
    """Bench entry point (see `taco_mav.bench`). Without `real_pairs` and with no set at the default place, the
    keys are absent and a warning says so (as the `real` section)."""
    cv2.setNumThreads(1)
    root = Path(real_pairs) if real_pairs else default_root()
    if not real_pairs and not root.is_dir():
        log.warning("bench real_signal: no real pairs at %s (give --real-pairs DIR or TACO_REAL_PAIRS): its keys "
                    "are absent", root)
        return {}
    return evaluate(root)
