"""Bench section: the classical matcher's speed and accuracy on rendered frames of a synthetic mosaic.

Frames are rendered at true poses (`GroundRenderer`), crops are cut heading-up (`SatelliteMap`) at the true
heading plus a small residual and centred at the true position plus a known offset in a random direction; the
matcher's fix (crop centre + t, rotated to ENU) is compared with the truth. Seeded: same seed, same figures
(timings aside).

Keys: classical_ms_per_trigger (five crops), classical_median_error_m_within_10m, classical_capture_radius_m
(first offset where success, error < 3 m, falls below 50 %), classical_success_vs_offset
([offset_m, success_rate, median_error_m] for 0..30 m in 2.5 m steps), classical_error_cdf (error quantiles);
w as a confidence (`confidence_figures`): classical_w_auc, classical_w_median_correct, classical_w_median_chance,
classical_success_vs_w.
"""

from __future__ import annotations

import logging
import math
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np
import rasterio
from rasterio.transform import from_origin

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig, ClassicalMatcherConfig, MapConfig
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.classical import ClassicalMatcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.datasets.synthetic.render import GroundRenderer

log = logging.getLogger(__name__)

SUCCESS_M = 3.0
WEST, NORTH = 500_000.0, 5_430_000.0  # top-left corner of the synthetic mosaic, UTM metres
CHANCE_MIN_DIST_M = 150.0  # a crop centred this far from the truth shows a different place
MARGIN_M = 130.0  # true poses stay this far inside the mosaic, so every crop lies on the map


def textured_mosaic(seed: int, size_px: int = 2000, m_per_px: float = 0.2) -> np.ndarray:
    """A structured test mosaic, uint8 RGB (size_px, size_px, 3): vegetation/soil noise, straight roads with
    lane markings, roofs with shadows and tree crowns. Deterministic in `seed`."""
    rng = np.random.default_rng(seed)
    S = size_px
    low = cv2.resize(rng.random((S // 100 + 2, S // 100 + 2, 3)).astype(np.float32), (S, S), interpolation=cv2.INTER_CUBIC)
    mid = cv2.resize(rng.random((S // 12, S // 12, 3)).astype(np.float32), (S, S), interpolation=cv2.INTER_CUBIC)
    fine = rng.random((S, S, 1)).astype(np.float32)
    base = np.array([70, 100, 55], np.float32) + 50 * (low - 0.5) + 30 * (mid - 0.5) + 25 * (fine - 0.5)
    img = np.clip(base, 0, 255).astype(np.uint8)
    px = 1.0 / m_per_px
    for _ in range(max(3, S // 160)):  # roofs with a shadow on one side
        w, h = rng.uniform(8, 30, 2) * px
        cx, cy = rng.uniform(0, S, 2)
        ang = rng.uniform(0, 180)
        box = cv2.boxPoints(((cx, cy), (w, h), ang)).astype(np.int32)
        cv2.fillConvexPoly(img, box + np.int32([int(1.5 * px), int(1.5 * px)]), (35, 40, 35))
        colour = tuple(int(c) for c in rng.choice([[150, 70, 60], [120, 120, 125], [190, 185, 175], [90, 90, 100]]))
        cv2.fillConvexPoly(img, box, colour)
        cv2.line(img, tuple(((box[0] + box[1]) // 2).tolist()), tuple(((box[2] + box[3]) // 2).tolist()),
                 tuple(max(c - 30, 0) for c in colour), max(1, int(0.3 * px)))
    for _ in range(S // 25):  # tree crowns
        c = tuple(int(v) for v in rng.uniform(0, S, 2))
        cv2.circle(img, c, int(rng.uniform(1.5, 4) * px), (40, 75, 35), -1)
    for _ in range(max(3, S // 350)):  # roads: asphalt, solid edge lines, dashed centre line
        p = rng.uniform(0.1 * S, 0.9 * S, 2)
        ang = rng.uniform(0, math.pi)
        d = np.array([math.cos(ang), math.sin(ang)])
        n = np.array([-d[1], d[0]])
        width = rng.uniform(7, 12) * px
        a, b = p - 2 * S * d, p + 2 * S * d
        cv2.line(img, tuple(a.astype(int)), tuple(b.astype(int)), (85, 85, 90), int(width))
        for side in (-1, 1):
            off = side * (width / 2 - 0.5 * px) * n
            cv2.line(img, tuple((a + off).astype(int)), tuple((b + off).astype(int)), (220, 220, 215), max(1, int(0.15 * px)))
        dash = 3.0 * px
        for k in range(int(4 * S / (2 * dash))):
            q0 = a + d * (2 * k * dash)
            cv2.line(img, tuple(q0.astype(int)), tuple((q0 + d * dash).astype(int)), (230, 230, 225), max(1, int(0.15 * px)))
    return img


def write_geotiff(path: Path, mosaic: np.ndarray, west: float, north: float, m_per_px: float, epsg: int = 32632) -> None:
    """Write an RGB uint8 mosaic as a north-up UTM GeoTIFF with its top-left corner at (west, north)."""
    with rasterio.open(path, "w", driver="GTiff", width=mosaic.shape[1], height=mosaic.shape[0], count=3,
                       dtype="uint8", crs=f"EPSG:{epsg}", transform=from_origin(west, north, m_per_px, m_per_px)) as ds:
        ds.write(mosaic.transpose(2, 0, 1))


@contextmanager
def synthetic_world(seed: int, size_px: int = 2500, m_per_px: float = 0.2
                    ) -> Iterator[tuple[GroundRenderer, SatelliteMap, GroundCamera]]:
    """A seeded textured mosaic as a temporary GeoTIFF: (renderer of ground frames at true poses, the open
    SatelliteMap, the KITTI-like ground camera). The mosaic's top-left corner is (WEST, NORTH) UTM metres."""
    mosaic = textured_mosaic(seed, size_px, m_per_px)
    cam = GroundCamera.from_config(CameraConfig())
    renderer = GroundRenderer(mosaic, from_origin(WEST, NORTH, m_per_px, m_per_px), cam, max_range_m=80.0)
    with tempfile.TemporaryDirectory() as tmp:
        tif = Path(tmp) / "mosaic.tif"
        write_geotiff(tif, mosaic, WEST, NORTH, m_per_px)
        with SatelliteMap(tif) as smap:
            yield renderer, smap, cam


def _random_pose(rng: np.random.Generator, extent_m: float) -> tuple[float, float, float]:
    """A true pose (E, N UTM metres, theta ENU rad) at least MARGIN_M inside the synthetic mosaic."""
    E = WEST + rng.uniform(MARGIN_M, extent_m - MARGIN_M)
    N = NORTH - rng.uniform(MARGIN_M, extent_m - MARGIN_M)
    return E, N, rng.uniform(-math.pi, math.pi)


def _fix_error(crop_centre: np.ndarray, heading: float, t: np.ndarray, true_en: np.ndarray) -> float:
    """Metres between the fix (crop centre + t, (forward, left) rotated by the crop heading) and the truth."""
    cs, ss = math.cos(heading), math.sin(heading)
    fix = crop_centre + t[0] * np.array([cs, ss]) + t[1] * np.array([-ss, cs])
    return float(np.hypot(*(fix - true_en)))


def evaluate(seed: int = 0, trials_per_offset: int = 12, offsets: np.ndarray | None = None,
             cfg: ClassicalMatcherConfig | None = None, progress: bool = False) -> dict[str, Any]:
    """Success and error vs crop offset, and the per-trigger time, on a seeded synthetic world."""
    cfg = cfg or ClassicalMatcherConfig()
    offsets = np.arange(0.0, 30.01, 2.5) if offsets is None else offsets
    rng = np.random.default_rng(seed)
    m_px, size = 0.2, 2500
    mcfg = MapConfig()
    rows, errors_within_10, all_errors, times = [], [], [], []
    with synthetic_world(seed, size, m_px) as (renderer, smap, cam):
        matcher = ClassicalMatcher(cfg, cam)
        for off in offsets:
            errs = []
            for _ in range(trials_per_offset):
                E, N, theta = _random_pose(rng, size * m_px)
                frame = GroundFrame(renderer.render((E, N, theta)), 0.0, cam)
                q_heading = theta + rng.uniform(-1, 1) * math.radians(3.0)
                direction = rng.uniform(-math.pi, math.pi)
                centre = np.array([E, N]) + off * np.array([math.cos(direction), math.sin(direction)])
                # five crops like a trigger: the offset one plus four around it (+-8 m)
                cs, ss = math.cos(q_heading), math.sin(q_heading)
                centres = [centre + dl for dl in (np.zeros(2), 8 * np.array([cs, ss]), -8 * np.array([cs, ss]),
                                                  8 * np.array([-ss, cs]), -8 * np.array([ss, -cs]))]
                crops = [smap.crop(c, q_heading, mcfg.crop_size_px, mcfg.crop_m_per_px) for c in centres]
                t0 = time.perf_counter()
                res = matcher.match(frame, crops)
                times.append(time.perf_counter() - t0)
                err = _fix_error(crops[0].centre_utm, q_heading, res[0].t, np.array([E, N]))
                errs.append(err)
                if off <= 10.0:
                    errors_within_10.append(err)
            errs_a = np.array(errs)
            all_errors.extend(errs)
            rows.append([float(off), float(np.mean(errs_a < SUCCESS_M)), float(np.median(errs_a))])
            if progress:
                log.info("classical bench: offset %.1f m success %.2f median %.2f m", off, rows[-1][1], rows[-1][2])
    capture = next((r[0] for r in rows if r[1] < 0.5), float(offsets[-1]))
    q = np.linspace(0.0, 1.0, 21)
    return {
        "classical_ms_per_trigger": float(np.median(times) * 1e3),
        "classical_median_error_m_within_10m": float(np.median(errors_within_10)),
        "classical_capture_radius_m": float(capture),
        "classical_success_vs_offset": rows,
        "classical_error_cdf": [[float(qq), float(v)] for qq, v in zip(q, np.quantile(all_errors, q))],
    }


def confidence_samples(seed: int = 1, trials: int = 240, chance_trials: int = 80, max_offset_m: float = 30.0,
                       cfg: ClassicalMatcherConfig | None = None) -> dict[str, np.ndarray]:
    """PSR, w and fix error of single-crop matches on a seeded synthetic world.

    `trials` crops are centred at the truth plus a uniform 0..max_offset_m offset in a random direction (query
    heading within +-3 deg of the truth); `chance_trials` crops come from a different place (centre at least
    CHANCE_MIN_DIST_M from the truth), so any peak is a chance peak. Returns arrays psr, w, error_m (metres) and
    chance (bool), in that order of trials.
    """
    cfg = cfg or ClassicalMatcherConfig()
    rng = np.random.default_rng(seed)
    size, m_px = 2500, 0.2
    extent = size * m_px
    mcfg = MapConfig()
    psr, w, err, chance = [], [], [], []
    with synthetic_world(seed, size, m_px) as (renderer, smap, cam):
        matcher = ClassicalMatcher(cfg, cam)
        for k in range(trials + chance_trials):
            E, N, theta = _random_pose(rng, extent)
            frame = GroundFrame(renderer.render((E, N, theta)), 0.0, cam)
            q_heading = theta + rng.uniform(-1, 1) * math.radians(3.0)
            is_chance = k >= trials
            if is_chance:
                centre = np.array([E, N])
                while np.hypot(*(centre - [E, N])) < CHANCE_MIN_DIST_M:
                    centre = np.array(_random_pose(rng, extent)[:2])
            else:
                direction = rng.uniform(-math.pi, math.pi)
                centre = np.array([E, N]) + rng.uniform(0.0, max_offset_m) * np.array([math.cos(direction),
                                                                                       math.sin(direction)])
            crop = smap.crop(centre, q_heading, mcfg.crop_size_px, mcfg.crop_m_per_px)
            (res,) = matcher.match(frame, [crop])
            psr.append(matcher.last_psr[0])
            w.append(res.w)
            err.append(_fix_error(crop.centre_utm, q_heading, res.t, np.array([E, N])))
            chance.append(is_chance)
    return {"psr": np.array(psr), "w": np.array(w), "error_m": np.array(err), "chance": np.array(chance)}


def confidence_figures(samples: dict[str, np.ndarray]) -> dict[str, Any]:
    """Bench keys for w as a confidence: ROC AUC of w for correct (error < SUCCESS_M) vs all other matches,
    median w of correct matches and of chance peaks (crops of a different place), and the observed success rate
    in w bins ([w_lo, w_hi, n, success_rate])."""
    w, ok, chance = samples["w"], (samples["error_m"] < SUCCESS_M) & ~samples["chance"], samples["chance"]
    pos, neg = w[ok], w[~ok]
    auc = float(np.mean(pos[:, None] > neg[None, :]) + 0.5 * np.mean(pos[:, None] == neg[None, :]))
    edges = [0.0, 0.1, 0.5, 0.9, 1.0 + 1e-9]
    bins = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (w >= lo) & (w < hi)
        bins.append([lo, min(hi, 1.0), int(m.sum()), float(ok[m].mean()) if m.any() else None])
    return {
        "classical_w_auc": auc,
        "classical_w_median_correct": float(np.median(pos)),
        "classical_w_median_chance": float(np.median(w[chance])),
        "classical_success_vs_w": bins,
    }


def run(progress: bool = False) -> dict[str, Any]:
    """Bench entry point (see `taco_mav.bench`)."""
    cv2.setNumThreads(1)
    figures = evaluate(seed=0, progress=progress)
    figures.update(confidence_figures(confidence_samples(seed=5)))  # seed 5: not used to calibrate w
    return figures
