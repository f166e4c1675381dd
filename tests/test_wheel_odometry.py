"""Wheel distances differenced to a speed and a yaw rate (core/wheel_odometry.py), and what cannot be."""

from __future__ import annotations

import math

import pytest

from taco_mav.core.wheel_odometry import WheelOdometry


def test_two_wheels_give_the_speed_at_the_reference_point_and_the_yaw_rate() -> None:
    # ArduPilot SITL's pair: encoder 1 at y = +0.075 (right), encoder 2 at -0.075; a left turn (CCW) at 0.5 rad/s
    odo = WheelOdometry((0.075, -0.075), 20.0)
    v, w = 2.0, 0.5
    right, left = v + w * 0.075, v - w * 0.075  # FRD: v_i = v - w_frd y_i, w_frd = -w_enu
    assert odo.add(10.0, (0.0, 0.0)) == "first"
    m = odo.add(10.05, (right * 0.05, left * 0.05))
    assert not isinstance(m, str)
    assert m.speed == pytest.approx(2.0) and m.yaw_rate == pytest.approx(0.5)
    assert m.t_mid == pytest.approx(10.025) and m.wheel_speeds == pytest.approx((right, left))


def test_wheels_off_the_centre_line_are_carried_to_it() -> None:
    odo = WheelOdometry((0.3, 0.1), 20.0)  # both right of the reference point, 0.2 m apart
    v, w = 1.0, -0.4  # turning right
    speeds = [v + w * y for y in (0.3, 0.1)]
    odo.add(0.0, (0.0, 0.0))
    m = odo.add(0.1, tuple(s * 0.1 for s in speeds))
    assert m.speed == pytest.approx(1.0) and m.yaw_rate == pytest.approx(-0.4)


def test_one_wheel_or_two_on_one_line_give_no_yaw_rate() -> None:
    one = WheelOdometry((0.0, 0.0), 20.0)
    one.add(0.0, (5.0,))
    m = one.add(0.5, (6.0,))
    assert m.speed == pytest.approx(2.0) and m.yaw_rate is None
    same = WheelOdometry((0.0, 0.0), 20.0)
    same.add(0.0, (0.0, 0.0))
    assert same.add(0.5, (1.0, 0.5)).yaw_rate is None


@pytest.mark.parametrize("t,d,reason", [
    (1.0, (0.02, 0.02), "repeat"),
    (0.5, (0.02, 0.02), "backstep"),
    (1.05, (0.02,), "count"),
    (1.05, (math.nan, 0.0), "nonfinite"),
    (1.05, (2.0, 2.0), "jump"),  # 2 m in 50 ms: 40 m/s
])
def test_what_cannot_be_differenced_is_refused_with_its_reason(t: float, d: tuple, reason: str) -> None:
    odo = WheelOdometry((0.1, -0.1), 20.0)
    odo.add(1.0, (0.0, 0.0))
    assert odo.add(t, d) == reason


def test_differencing_starts_again_after_a_jump() -> None:
    odo = WheelOdometry((0.1, -0.1), 20.0)
    odo.add(1.0, (0.0, 0.0))
    assert odo.add(1.05, (5.0, 5.0)) == "jump"  # an encoder that skipped
    m = odo.add(1.10, (5.1, 5.1))
    assert m.speed == pytest.approx(2.0) and m.t0 == pytest.approx(1.05)
