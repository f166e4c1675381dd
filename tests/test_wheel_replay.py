"""A recording's wheel encoders replayed into the Localiser (evaluation/wheel_replay.py) as the daemon feeds them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import simulate, wheel_distances
from test_localiser_wheels import POS_Y, WHEELS

from taco_mav.core.localiser import make_localiser
from taco_mav.datasets.base import WheelLog
from taco_mav.evaluation.wheel_replay import WheelReplay


def test_recorded_wheels_reach_the_filter_at_their_time() -> None:
    d = simulate(lambda t: min(3.0, 0.5 + t), lambda t: 0.05, 20.0, rate_hz=50.0, accel_noise=0.02, seed=4)
    k = np.arange(0, len(d.t), 2)  # 25 Hz
    log = WheelLog(d.t[k], wheel_distances(d, POS_Y)[k], pos_y_m=(0.1, -0.1))
    loc = make_localiser(WHEELS, 0.0, heading=float(d.theta[0]), speed=0.5)
    replay = WheelReplay(log, WHEELS.wheels)
    assert replay.odometry.pos_y == POS_Y  # the profile's, as pos_y_from_autopilot is off
    for s in d.samples:
        loc.add_imu(s)
        replay.tick(loc, s.t)
    assert replay.counts["first"] == 1 and replay.counts["used"] >= len(k) - 3
    assert loc.estimate().speed == pytest.approx(3.0, abs=0.05)
    auto = dataclasses.replace(WHEELS.wheels, pos_y_from_autopilot=True)
    assert WheelReplay(log, auto).odometry.pos_y == (0.1, -0.1)  # the recorded WENC_POS_Y / WENC2_POS_Y
