"""Bench: fusion cost (preintegration + frame-rate UKF over 100 Hz IMU and 10 Hz frames, no matcher)."""

from __future__ import annotations

import math
import time

import numpy as np

from taco_mav.core.localiser_plus import make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus import PlusParams
from taco_mav.core.types import ImuSample

G = 9.80665


def _drive(duration_s: float, rate_hz: float = 100.0, seed: int = 0) -> list[ImuSample]:
    """A gently weaving 10 m/s drive with MEMS-like noise: FRD specific force incl. gravity, NED attitude."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    out = []
    theta = 0.0
    for i in range(n):
        t = i / rate_hz
        w = 0.1 * math.sin(0.2 * t)
        theta += w / rate_hz
        out.append(ImuSample(t, (0.3 * math.sin(0.5 * t) + rng.normal(0, 0.05), -10.0 * w, -G + rng.normal(0, 0.05)),
                             (0.0, 0.0, -w), 0.0, 0.0, math.pi / 2 - theta))
    return out


def _ms_per_data_second(params: LocaliserParams, samples: list[ImuSample], duration: float) -> float:
    times = []
    for _ in range(5):
        loc = make_localiser(params, 0.0, heading=math.pi / 2, speed=10.0, record=False)
        start = time.perf_counter()
        for s in samples:
            loc.add_imu(s)
        times.append((time.perf_counter() - start) / duration * 1000.0)
    return round(float(np.median(times)), 4)


def run(progress: bool = False) -> dict[str, float]:
    """fusion_ms_per_data_second (paper mode) and fusion_plus_ms_per_data_second (taco+: 5 states, ZUPT
    detection): median of 5 runs over 120 s of data with the triggers disabled."""
    duration = 120.0
    samples = _drive(duration)
    paper = LocaliserParams(trigger_epsilon_m=math.inf, trigger_time_s=math.inf)
    plus = LocaliserParams(plus=PlusParams(trigger_sigma_m=math.inf, trigger_time_s=math.inf, capture_radius_m=math.inf))
    return {"fusion_ms_per_data_second": _ms_per_data_second(paper, samples, duration),
            "fusion_plus_ms_per_data_second": _ms_per_data_second(plus, samples, duration)}
