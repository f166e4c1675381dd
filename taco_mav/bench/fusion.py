"""Bench: fusion cost (preintegration + frame-rate UKF over 100 Hz IMU and 10 Hz frames, no matcher).

Keys, each the median of 5 runs over 120 s of data (triggers disabled), milliseconds per second of data:
- fusion_ms_per_data_second: paper mode, wall clock (perf_counter);
- fusion_plus_ms_per_data_second: taco+ (5-6 states, ZUPT detection, safety guard), wall clock;
- fusion_cpu_ms_per_data_second / fusion_plus_cpu_ms_per_data_second: the same runs in this thread's CPU time,
  which other processes on a busy machine inflate much less than the wall clock.
The compiled kernels (core/ukf_kernels.py, numba) are compiled or loaded from their cache before timing, and
one untimed run warms the interpreter, so the figures are steady state.
"""

from __future__ import annotations

import math
import time

import numpy as np

from taco_mav.core import ukf_kernels
from taco_mav.core.localiser import make_localiser
from taco_mav.core.params import LocaliserParams, TriggerParams
from taco_mav.core.plus.params import PlusParams
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


def _ms_per_data_second(params: LocaliserParams, samples: list[ImuSample], duration: float) -> tuple[float, float]:
    """(wall, CPU) milliseconds per data second, medians of 5 timed runs after one untimed run."""
    wall, cpu = [], []
    for k in range(6):
        loc = make_localiser(params, 0.0, heading=math.pi / 2, speed=10.0, record=False)
        c0, w0 = time.thread_time(), time.perf_counter()
        for s in samples:
            loc.add_imu(s)
        if k:
            wall.append((time.perf_counter() - w0) / duration * 1000.0)
            cpu.append((time.thread_time() - c0) / duration * 1000.0)
    return round(float(np.median(wall)), 4), round(float(np.median(cpu)), 4)


def run(progress: bool = False) -> dict[str, float]:
    """fusion_ms_per_data_second (paper mode) and fusion_plus_ms_per_data_second (taco+: 5 states, ZUPT
    detection), wall clock, and their CPU-time twins: medians of 5 runs over 120 s of data with the triggers
    disabled."""
    ukf_kernels.warm_up()  # JIT compilation (or the cache load) is not steady state
    duration = 120.0
    samples = _drive(duration)
    paper = LocaliserParams(trigger=TriggerParams(epsilon_m=math.inf, time_s=math.inf))
    plus = LocaliserParams(plus=PlusParams(trigger_sigma_m=math.inf, trigger_time_s=math.inf, capture_radius_m=math.inf))
    paper_wall, paper_cpu = _ms_per_data_second(paper, samples, duration)
    plus_wall, plus_cpu = _ms_per_data_second(plus, samples, duration)
    return {"fusion_ms_per_data_second": paper_wall, "fusion_plus_ms_per_data_second": plus_wall,
            "fusion_cpu_ms_per_data_second": paper_cpu, "fusion_plus_cpu_ms_per_data_second": plus_cpu}
