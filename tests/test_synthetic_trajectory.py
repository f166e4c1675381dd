"""Route and kinematics: bounded accelerations, consistent speed/heading/position, stops, revisit."""

from __future__ import annotations

import numpy as np
import pytest

from taco_mav.datasets.synthetic.roads import grid_network, plan_route, route_polyline
from taco_mav.datasets.synthetic.trajectory import drive_kinematics, smooth_path


@pytest.fixture(scope="module", params=[0, 1, 2])
def kin(request):
    rng = np.random.default_rng(request.param)
    net = grid_network(rng, 4, 4)
    route = plan_route(net, rng, 1000.0)
    line, jidx, off = route_polyline(net, route)
    return drive_kinematics(line, jidx, rng, offset_right=off)


def test_speed_and_accelerations_are_car_like(kin):
    assert kin.speed.min() >= 0.0 and kin.speed.max() <= 12.0 + 1e-9
    assert np.abs(kin.accel_fwd).max() < 2.3
    assert np.abs(kin.accel_lat).max() < 2.3
    assert 7.0 < kin.speed[kin.speed > 1.0].max() <= 12.0
    assert np.all(kin.speed[:250] == 0.0) or kin.speed[:250].max() < 0.05  # rests at the start


def test_position_is_the_integral_of_speed_along_heading(kin):
    dt = np.diff(kin.t)
    step = kin.speed[:, None] * np.c_[np.cos(kin.heading), np.sin(kin.heading)]
    xy = kin.xy[0] + np.r_[[[0.0, 0.0]], np.cumsum(0.5 * (step[1:] + step[:-1]) * dt[:, None], axis=0)]
    assert np.linalg.norm(xy - kin.xy, axis=1).max() < 0.005 * kin.s[-1]
    heading = kin.heading[0] + np.r_[0.0, np.cumsum(0.5 * (kin.yaw_rate[1:] + kin.yaw_rate[:-1]) * dt)]
    assert np.abs(heading - kin.heading).max() < 0.02


def test_length_and_revisit(kin):
    assert 900.0 < kin.s[-1] < 2200.0
    xy, s = kin.xy[::20], kin.s[::20]
    assert np.any((np.linalg.norm(xy[:, None] - xy[None], axis=2) <= 10.0) & (np.abs(s[:, None] - s[None]) >= 200.0))


def test_right_angle_turn_radius():
    """A 90 degree corner becomes a turn of >= 12 m radius on the centreline (>= 9 m on the inner lane)."""
    line = np.r_[[[x, 0.0] for x in range(-80, 1)], [[0.0, -y] for y in range(1, 81)]].astype(float)
    _, _, _, k = smooth_path(line)
    assert 1.0 / np.abs(k).max() > 12.0
    _, _, _, k_in = smooth_path(line, offset_right=np.full(len(line), 3.0))
    assert 1.0 / np.abs(k_in).max() > 9.0
