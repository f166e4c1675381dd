"""Bench: the FG2-statistics emulator reproduces its configured error figures.

20 000 in-radius draws (true offsets uniform in a 15 m disc, seed 0) through `EmulatorMatcher.match` with the
failure modes switched off give `emulator_median_error_m` / `emulator_mean_error_m` (same-area; FG2: 0.51 / 0.75
m) and the `emulator_cross_area_*` pair (4.15 / 7.31 m). With the default failure rates on, the shares of
symmetric locks and silent outliers are reported as `emulator_lock_rate` / `emulator_outlier_rate`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from tqdm import tqdm

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig, EmulatorConfig
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.cvgl.emulator import EmulatorMatcher, Outcome

N_DRAWS = 20_000


def sample(cfg: EmulatorConfig, n: int, cross_area: bool, seed: int = 0, progress: bool = False) -> tuple[np.ndarray, list[Outcome]]:
    """Position errors (metres, (n,)) and outcomes of n single-crop queries with the truth inside 15 m."""
    rng = np.random.default_rng(seed)
    r = 15.0 * np.sqrt(rng.random(n))
    a = rng.uniform(-np.pi, np.pi, n)
    camera = GroundCamera.from_config(CameraConfig())
    empty = np.zeros((0, 0, 3), np.uint8)
    errors, outcomes = np.empty(n), []
    truth_xy = np.c_[r * np.cos(a), r * np.sin(a)]
    matcher = EmulatorMatcher(cfg, lambda t: (*truth_xy[int(round(t * 10))], 0.3), cross_area, seed=seed)
    for i in tqdm(range(n), disable=not progress, desc="emulator"):
        crop = Crop(empty, np.zeros(2), heading=0.3, m_per_px=0.2)
        res = matcher.match(GroundFrame(empty, i / 10.0, camera), [crop])[0]
        ct, st = np.cos(0.3), np.sin(0.3)
        t_true = np.array([truth_xy[i] @ [ct, st], truth_xy[i] @ [-st, ct]])
        errors[i] = np.hypot(*(res.t - t_true))
        outcomes.append(matcher.last_draws[0].outcome)
    return errors, outcomes


def run(progress: bool = False) -> dict[str, float]:
    """Emulated error medians/means (metres) and failure-mode rates."""
    cfg = EmulatorConfig()
    clean = dataclasses.replace(cfg, symmetric_lock_rate=0.0, silent_outlier_rate=0.0)
    out: dict[str, float] = {}
    for key, cross in (("emulator", False), ("emulator_cross_area", True)):
        err, _ = sample(clean, N_DRAWS, cross, progress=progress)
        out[f"{key}_median_error_m"] = float(np.median(err))
        out[f"{key}_mean_error_m"] = float(np.mean(err))
    _, outcomes = sample(cfg, N_DRAWS, False, seed=1, progress=progress)
    out["emulator_lock_rate"] = outcomes.count(Outcome.LOCK) / N_DRAWS
    out["emulator_outlier_rate"] = outcomes.count(Outcome.OUTLIER) / N_DRAWS
    return out
