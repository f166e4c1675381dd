"""taco+'s wheel-speed checks (core/plus/wheel_speed.py): a stuck encoder, a wheel in the air, a wheel speed far
above the filter's are refused, and the source itself after a few in a row; a stop the IMU sees is taken; the
source comes back once enough agree again."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import simulate, wheel_distances
from test_localiser_wheels import POS_Y, WHEELS

from taco_mav.core.corrections import WheelSpeed
from taco_mav.core.localiser import make_localiser
from taco_mav.core.wheel_odometry import WheelOdometry


def _drive(speed=lambda t: min(3.0, 0.5 + t)):
    return simulate(speed, lambda t: 0.0, 40.0, rate_hz=50.0, accel_noise=0.02, gyro_noise=0.0005,
                    compass_noise=0.002, seed=5)


def _feed(d, fault=None, after: float = 20.0):
    """Run `d` with 20 Hz wheels and the autopilot's drive command; from `after` s on, `fault(t, distances) ->
    distances` changes what the encoders say. Returns the Localiser and the verdicts (t, verdict)."""
    loc = make_localiser(WHEELS, 0.0, heading=float(d.theta[0]), speed=float(d.speed[0]))
    odo = WheelOdometry(POS_Y, 20.0)
    dist = wheel_distances(d, POS_Y)
    verdicts, next_w = [], 0.0
    for k, s in enumerate(d.samples):
        loc.add_imu(s)
        loc.set_drive_command(s.t, bool(d.speed[k] > 0.0))  # the autopilot's throttle (VFR_HUD), as the daemon
        if s.t >= next_w - 1e-9:
            next_w += 0.05
            dk = dist[k] if fault is None or s.t < after else fault(s.t, dist[k])
            m = odo.add(round(s.t, 3), dk)
            if not isinstance(m, str):
                verdicts.append((s.t, loc.aids.add_wheel_speed(m)))
    return loc, verdicts


def test_honest_wheels_are_used_and_kept_on_their_frames() -> None:
    loc, verdicts = _feed(_drive())
    assert sum(v == "used" for _, v in verdicts) >= len(verdicts) - 2  # the first one or two: stale
    kept = [c for h in loc.timeline.history for c in h.corrections if isinstance(c, WheelSpeed)]
    assert len(kept) == len(loc.timeline.history)  # one per frame, replayed with it
    assert loc.estimate().speed == pytest.approx(3.0, abs=0.05)


def test_a_stuck_encoder_is_refused_and_the_speed_stays_the_imus() -> None:
    frozen = {}
    loc, verdicts = _feed(_drive(), lambda t, d: frozen.setdefault("d", d.copy()))
    after = [v for t, v in verdicts if t > 20.1]
    assert after[:3] == ["stuck", "stuck", "stuck"] and set(after) == {"stuck"}
    assert loc.aids.wheels_refused() == "stuck"
    assert loc.estimate().speed == pytest.approx(3.0, abs=0.3)  # not pulled to 0


def test_a_wheel_in_the_air_is_slip() -> None:
    start = {}

    def spinning(t, d):  # the right wheel spins freely at twice its speed
        d0 = start.setdefault("d", d.copy())
        return np.array([d0[0] + 2.0 * (d[0] - d0[0]), d[1]])

    loc, verdicts = _feed(_drive(), spinning)
    after = [v for t, v in verdicts if t > 20.1]
    assert set(after) == {"slip"} and loc.aids.wheels_refused() == "slip"


def test_wheels_far_faster_than_the_filter_are_slip_without_a_yaw_rate() -> None:
    start = {}

    def slipping(t, d):  # both wheels spin 40 % fast (mud): no yaw rate to tell
        d0 = start.setdefault("d", d.copy())
        return d0 + 1.4 * (d - d0)

    loc, verdicts = _feed(_drive(), slipping)
    assert {v for t, v in verdicts if t > 20.5} == {"slip"}
    assert loc.estimate().speed == pytest.approx(3.0, abs=0.3)


def test_a_real_stop_is_taken_and_the_source_comes_back_after_agreeing_again() -> None:
    # 3 m/s, a stop from 15 to 25 s, on again; the encoders freeze from 10 s to 12 s (a loose connector) only
    d = _drive(lambda t: 0.0 if 15.0 < t < 25.0 else min(3.0, 0.5 + t) if t <= 15.0 else min(3.0, t - 25.0))
    frozen = {}
    loc, verdicts = _feed(d, lambda t, x: frozen.setdefault("d", x.copy()) if t < 12.0 else x, after=10.0)
    assert loc.aids.wheels_refused() is None
    assert "stuck" in {v for t, v in verdicts if 10.1 < t < 12.0}
    assert {v for t, v in verdicts if 18.0 < t < 24.0} == {"used"}  # standing wheels at a stop: used
    assert {v for t, v in verdicts if t > 30.0} == {"used"}
    assert math.isclose(loc.estimate().speed, float(d.speed[-1]), abs_tol=0.1)
