"""ClockMap: TIMESYNC round trips, SYSTEM_TIME and IMU fallbacks, priority and staleness, on an injected clock."""

from __future__ import annotations

import pytest

from taco_mav.mavlink.timesync import ClockMap


class Clock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_timesync_offset_uses_shortest_round_trip() -> None:
    clk = Clock()
    cm = ClockMap(clk)
    assert cm.offset is None and cm.to_autopilot(5.0) is None
    true_offset = -900.0  # autopilot = companion - 900
    for rtt, asym in ((0.200, 0.15), (0.010, 0.005), (0.100, 0.08)):
        ts1 = cm.request_ns()
        # the autopilot stamps its clock after `asym` of the round trip
        tc1 = int((clk.t + asym + true_offset) * 1e9)
        clk.t += rtt
        assert cm.on_timesync_reply(tc1, ts1)
    assert cm.source == "timesync"
    assert cm.offset == pytest.approx(true_offset, abs=0.001)  # the 10 ms trip: error <= 5 ms... here 0
    assert cm.to_companion(cm.to_autopilot(123.0)) == pytest.approx(123.0)


def test_timesync_rejects_implausible() -> None:
    clk = Clock()
    cm = ClockMap(clk, max_rtt_s=0.5)
    ts1 = cm.request_ns()
    clk.t += 2.0
    assert not cm.on_timesync_reply(5_000_000_000, ts1)
    assert not cm.on_timesync_reply(0, cm.request_ns())
    assert cm.offset is None


def test_fallbacks_and_priority() -> None:
    clk = Clock()
    cm = ClockMap(clk, stale_s=5.0)
    cm.on_autopilot_time(50.0)  # arrived 20 ms late: offset looks 20 ms small
    clk.t += 0.1
    cm.on_autopilot_time(50.12)
    assert cm.source == "imu" and cm.offset == pytest.approx(50.12 - 1000.1)
    cm.on_system_time(50_200)
    assert cm.source == "system_time" and cm.offset == pytest.approx(50.2 - 1000.1)
    ts1 = cm.request_ns()
    clk.t += 0.01
    cm.on_timesync_reply(int(50.215 * 1e9), ts1)
    assert cm.source == "timesync"
    clk.t += 6.0  # timesync stale, SYSTEM_TIME keeps coming
    cm.on_system_time(56_300)
    assert cm.source == "system_time"
    cm.reset()
    assert cm.source is None


def test_theil_sen_slope_is_scipys() -> None:
    """The loop's own Theil-Sen slope (ClockRate, 10 Hz) gives scipy.stats.theilslopes' numbers exactly, ties
    in x included."""
    import numpy as np
    from scipy import stats

    from taco_mav.mavlink.timesync import theil_sen_slope

    rng = np.random.default_rng(3)
    for n in (3, 4, 17, 50):
        for k in range(20):
            x = np.sort(rng.uniform(0.0, 5.0, n))
            if k % 2:
                x = np.round(x, 1)  # repeated x: those pairs are left out, as scipy does
            y = 1.02 * x + rng.normal(0.0, 0.01, n)
            assert theil_sen_slope(y, x) == stats.theilslopes(y, x).slope
