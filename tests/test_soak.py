"""Soak, short: 3 simulated minutes through the real daemon at 5x (lockstep simulator over loopback UDP). Lockstep
holds the clock for GPS_INPUT, not for the matcher's worker thread, so a stall of the runner is 5-20x as long in
data time without fixes: at 20x one CI run reported accuracy above 10 m for 4 s (20 of 900 outputs no fix), at 10x
another (loaded by the closed-loop tests before it) for 2 s (10 of 900).
Every growing structure stays within its bound, the GPS_INPUT rate is 300 per data minute, no gap pair over
245 ms. The hour-long run is `python tools/soak.py --hours 1 --speed 20 --out soak.json`."""

from __future__ import annotations

import math
import mmap
import threading

import numpy as np

from taco_mav.geo import UtmProjector
from taco_mav.reliability.soak import circle_drive, rss_mb, soak


def test_three_minutes_bounded_and_steady() -> None:
    parked = threading.Event()  # a thread alive before the run (as other tests leave): not the daemon's
    other = threading.Thread(target=parked.wait, daemon=True)
    other.start()
    try:
        doc = soak(hours=0.05, speed=5.0)
    finally:
        parked.set()
    per_min = doc["gps_input_per_min"]
    assert len(per_min) == 3 and all(297 <= n <= 303 for n in per_min), per_min  # 5 Hz in data time
    assert doc["consecutive_gaps_over_245ms"] == 0
    for name, bound in doc["sizes_bound"].items():
        if bound is not None:
            assert doc["sizes_max"][name] <= bound, (name, doc["sizes_max"][name], bound)
    sizes = doc["sizes_max"]
    assert sizes["localiser.history"] >= 100  # the 10 s history is full, and no larger
    assert sizes["fixes.results_queue"] <= 2 and sizes["counter_keys"] <= 8 and 3 <= sizes["threads"] <= 8
    assert doc["daemon"]["fixes"].get("accepted", 0) >= 60 and doc["daemon"]["link_outages"] == 0
    counts = doc["fix_type_counts"]
    assert counts.get("3", 0) >= 0.99 * sum(counts.values())
    assert doc["ate_m"] < 3.0
    assert doc["rss_mb"]["end"] > 50.0 and doc["log_bytes_end"] > 100_000  # measured, and logs were written


def test_circle_drive_is_a_consistent_lap() -> None:
    d = circle_drive(120.0, rate_hz=10.0, radius_m=150.0, speed_mps=8.0)
    assert len(d) == 1201 and math.isclose(d.data_rate_hz, 10.0, rel_tol=1e-9)
    centre = np.array([0.0, 150.0])
    assert np.allclose(np.linalg.norm(d.truth.xy - centre, axis=1), 150.0)
    step = np.linalg.norm(np.diff(d.truth.xy, axis=0), axis=1)
    assert np.allclose(step, 0.8, atol=1e-3)  # 8 m/s at 10 Hz
    assert np.allclose(d.accel_frd[:, 1], -8.0 * 8.0 / 150.0) and np.allclose(d.gyro_frd[:, 2], -8.0 / 150.0)
    assert np.allclose(np.hypot(d.vn, d.ve), 8.0)
    proj = UtmProjector(d.utm_epsg)
    e, n = proj.to_utm(d.true_lat, d.true_lon)
    assert np.allclose(np.c_[e, n] - d.origin_utm, d.truth.xy, atol=1e-3)
    # NED yaw of the first sample: heading east on the grid = 90 deg true, less the convergence
    conv = float(proj.grid_convergence(d.lat[0], d.lon[0]))
    assert math.isclose(d.true_yaw_ned[0], math.pi / 2 + conv, abs_tol=1e-9)


def test_rss_reads_this_process() -> None:
    """50 MiB of fresh anonymous pages, written: the resident set grows by them. (An array from the heap could
    reuse pages an allocator kept resident from an earlier test: then nothing grows.)"""
    before = rss_mb()
    block = mmap.mmap(-1, 50 * 2**20)
    try:
        block.write(b"\x01" * len(block))
        assert rss_mb() - before > 40.0
    finally:
        block.close()
