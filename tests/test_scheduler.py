"""Periodic: steady grid, no drift from jitter, no bursts after a stall; and the output health state machine."""

from __future__ import annotations

import numpy as np
import pytest

from taco_mav.daemon.health import Health
from taco_mav.daemon.scheduler import Periodic


def test_steady_intervals_under_jitter() -> None:
    rng = np.random.default_rng(0)
    p = Periodic(5.0, start=0.0)
    fired = []
    t = 0.0
    while t < 20.0:
        if p.due(t):
            fired.append(t)
        t += float(rng.uniform(0.001, 0.02))  # a loop waking every 1-20 ms
    gaps = np.diff(fired)
    assert len(fired) == pytest.approx(100, abs=1)
    assert gaps.mean() == pytest.approx(0.2, abs=0.002)
    assert gaps.max() < 0.221 and gaps.min() > 0.179  # each slot within one loop period of the grid


def test_late_loop_skips_instead_of_bursting() -> None:
    p = Periodic(10.0, start=0.0)
    assert p.due(0.0)
    assert p.due(0.55)  # stalled 0.55 s: one send, slots 0.1..0.5 skipped
    assert p.skipped == 4
    assert not p.due(0.58)
    assert p.due(0.6)
    assert p.wait(0.62) == pytest.approx(0.08)


def test_health_hysteresis_and_stall() -> None:
    h = Health(degrade_accuracy_m=10.0, recover_accuracy_m=8.0, stall_s=0.5)
    assert h.update(3.0, 0.01) is None and h.healthy
    assert h.update(10.5, 0.01) == "degraded: accuracy 10.5m"
    assert h.update(9.0, 0.01) is None and not h.healthy  # between recover and degrade: stays degraded
    assert h.update(7.9, 0.01).startswith("recovered") and h.healthy
    assert h.update(3.0, 0.6) == "degraded: IMU stalled 0.6s"
    assert h.update(9.0, 0.01).startswith("recovered")  # stall cleared; 9 m < 10 m is fine
    assert h.update(float("nan"), 0.0) == "degraded: estimate not finite"
