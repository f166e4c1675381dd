import math

import numpy as np
import pytest
from helpers import G, simulate

from taco_mav.core.preintegration import Preintegrator, enu_heading, level_forward_accel
from taco_mav.core.types import ImuSample


def _circle(pitch: float = 0.0, roll: float = 0.0):
    v, r = 10.0, 50.0
    return simulate(lambda t: v, lambda t: v / r, 2 * math.pi * r / v, rate_hz=100.0, pitch=pitch, roll=roll)


@pytest.mark.parametrize("pitch,roll", [(0.0, 0.0), (0.08, -0.05)])
def test_constant_speed_circle_reproduced_within_one_percent(pitch, roll):
    d = _circle(pitch, roll)
    pre = Preintegrator(0.0, 0.0, 0.0, float(d.theta[0]), 10.0)
    path = []
    for s in d.samples[1:]:
        pre.add(s)
        path.append((pre.x, pre.y))
    err = np.linalg.norm(np.array(path) - d.xy[1:], axis=1)
    assert d.length == pytest.approx(2 * math.pi * 50, rel=1e-3)
    assert err.max() <= 0.01 * d.length
    assert pre.speed == pytest.approx(10.0, abs=1e-6)


def test_increments_compose_to_the_dead_reckoned_path_and_are_exact_for_arcs():
    d = _circle()
    pre = Preintegrator(0.0, 0.0, 0.0, float(d.theta[0]), 10.0)
    x = y = 0.0
    incs = []
    for i, s in enumerate(d.samples[1:], start=1):
        theta_start = pre._theta0
        pre.add(s)
        if i % 10 == 0:
            inc = pre.take_increment()
            incs.append(inc)
            x += math.cos(theta_start) * inc.d_fwd - math.sin(theta_start) * inc.d_left
            y += math.sin(theta_start) * inc.d_fwd + math.cos(theta_start) * inc.d_left
    theta_start = pre._theta0
    last = pre.take_increment()
    x += math.cos(theta_start) * last.d_fwd - math.sin(theta_start) * last.d_left
    y += math.sin(theta_start) * last.d_fwd + math.cos(theta_start) * last.d_left
    assert (x, y) == pytest.approx((pre.x, pre.y), abs=1e-9)
    # one 0.1 s frame on a 50 m circle at 10 m/s: dtheta = 0.02 rad, chord = 2 r sin(dtheta / 2)
    inc = incs[5]
    assert inc.d_theta == pytest.approx(0.02, abs=1e-9)
    assert inc.d_fwd == pytest.approx(50 * math.sin(0.02), abs=1e-4)
    assert inc.d_left == pytest.approx(50 * (1 - math.cos(0.02)), abs=1e-4)
    assert inc.distance == pytest.approx(1.0, abs=1e-9)


def test_gravity_is_compensated_on_a_tilted_vehicle_at_rest():
    for pitch, roll in [(0.1, 0.0), (-0.2, 0.15), (0.0, 0.3)]:
        # FRD specific force at rest: f_b = C_nb^T (0, 0, -g)
        sp, cp, sr, cr = math.sin(pitch), math.cos(pitch), math.sin(roll), math.cos(roll)
        f = (G * sp, -G * cp * sr, -G * cp * cr)
        assert level_forward_accel(f, roll, pitch) == pytest.approx(0.0, abs=1e-12)
    # level at rest reads z = -g in FRD; a forward push of 1 m/s^2 reads as 1 m/s^2
    assert level_forward_accel((1.0, 0.0, -G), 0.0, 0.0) == pytest.approx(1.0)


def test_irregular_dt_and_stale_samples():
    pre = Preintegrator(0.0, theta=0.0, speed=0.0)
    t = 0.0
    rng = np.random.default_rng(3)
    for _ in range(200):
        t += rng.uniform(0.0025, 0.1)
        pre.add(ImuSample(t, (1.0, 0.0, -G), (0, 0, 0), 0.0, 0.0, math.pi / 2))
    assert pre.speed == pytest.approx(t, rel=1e-9)  # v = a t from rest
    assert pre.x == pytest.approx(0.5 * t * t, rel=1e-9)  # trapezoid is exact for constant acceleration
    assert pre.add(ImuSample(t, (1.0, 0.0, -G), (0, 0, 0), 0.0, 0.0, math.pi / 2)) == 0.0  # repeated time: ignored
    assert pre.add(ImuSample(t - 1, (1.0, 0.0, -G), (0, 0, 0), 0.0, 0.0, math.pi / 2)) == 0.0  # backwards: ignored


def test_speed_clamped_at_zero_unless_reverse_allowed():
    for allow, expected in [(False, 0.0), (True, -1.0)]:
        pre = Preintegrator(0.0, speed=0.0, allow_reverse=allow)
        for i in range(1, 101):
            pre.add(ImuSample(i * 0.01, (-1.0, 0.0, -G), (0, 0, 0), 0.0, 0.0, 0.0))
        assert pre.speed == pytest.approx(expected, abs=1e-9)


def test_position_reset_keeps_heading_and_speed():
    pre = Preintegrator(0.0, 5.0, 5.0, 1.0, 7.0)
    pre.reset_position(-3.0, 4.0)
    assert (pre.x, pre.y, pre.theta, pre.speed) == (-3.0, 4.0, 1.0, 7.0)


def test_enu_heading_from_ned_yaw():
    assert enu_heading(0.0) == pytest.approx(math.pi / 2)  # north
    assert enu_heading(math.pi / 2) == pytest.approx(0.0)  # east
    assert enu_heading(math.pi) == pytest.approx(-math.pi / 2)  # south
    assert abs(enu_heading(-math.pi / 2)) == pytest.approx(math.pi)  # west


def _level_drive(pitch_reported, tilt_lowpass_s: float, seconds: float = 10.0, accel: float = 1.0) -> Preintegrator:
    """A level vehicle pulling away at `accel` m/s^2 (exact IMU at 50 Hz) whose attitude source reports the pitch
    `pitch_reported(t)`, rad."""
    pre = Preintegrator(0.0, theta=0.0, speed=0.0, tilt_lowpass_s=tilt_lowpass_s)
    for i in range(1, int(seconds * 50) + 1):
        t = i / 50.0
        pre.add(ImuSample(t, (accel, 0.0, -G), (0, 0, 0), 0.0, float(pitch_reported(t)), math.pi / 2))
    return pre


def test_a_wobbling_reported_pitch_is_low_passed_out_of_the_speed():
    """An autopilot whose EKF fuses our output reports a pitch that wobbles (SITL EKF3: 0.3 deg, std, on
    level ground). Taken sample by sample it integrates into the speed; low-passed over 30 s (the rover profiles) a
    20 s wobble of 0.4 deg costs a sixth of that."""
    wobble = lambda t: math.radians(0.4) * math.sin(2 * math.pi * t / 20.0)  # noqa: E731
    raw = _level_drive(wobble, 0.0)
    low = _level_drive(wobble, 30.0)
    # sample by sample: g sin(0.4 deg) over half a period, integrated: 0.0685 * 20 / pi = 0.44 m/s too slow
    assert 10.0 - raw.speed == pytest.approx(0.436, abs=0.01)
    assert abs(10.0 - low.speed) < 0.2 * (10.0 - raw.speed)  # 0.07 m/s
    assert low.tilt is not None and abs(low.tilt[1]) < math.radians(0.1)


def test_the_tilt_low_pass_starts_from_the_first_attitude_and_follows_a_grade():
    """A vehicle at rest on a 3 deg grade from the first sample reads no forward acceleration (the low-pass starts
    at the first attitude, not at level); after a change of grade the low-pass catches up within a few time
    constants, and from_params takes the profile's time constant."""
    from taco_mav.core.params import ImuParams

    def rest(pitch_of_t, seconds: float) -> Preintegrator:
        pre = Preintegrator.from_params(ImuParams(tilt_lowpass_s=5.0), 0.0, 0.0, 0.0, 0.0, 0.0)
        assert pre.tilt_lowpass_s == 5.0
        worst = 0.0
        for i in range(1, int(seconds * 50) + 1):
            t = i / 50.0
            p = pitch_of_t(t)
            pre.add(ImuSample(t, (G * math.sin(p), 0.0, -G * math.cos(p)), (0, 0, 0), 0.0, p, math.pi / 2))
            worst = max(worst, abs(pre.accel_fwd))
        return pre, worst

    grade = math.radians(3.0)
    _, worst = rest(lambda t: grade, 5.0)
    assert worst < 1e-9
    pre, _ = rest(lambda t: 0.0 if t < 1.0 else grade, 26.0)  # a new grade at 1 s, five time constants before
    assert abs(pre.accel_fwd) < G * grade * math.exp(-5.0) * 1.1


def test_the_tilt_low_pass_leaves_the_gyro_heading_levelled_by_each_sample():
    """gyro_heading (the PX4 profiles) levels the gyro's yaw rate by the attitude of the moment; the tilt low-pass
    is for gravity only, so a rover rolling and pitching while it turns keeps the same heading with it or without."""
    pres = [Preintegrator(0.0, theta=0.3, speed=2.0, tilt_lowpass_s=tau) for tau in (0.0, 30.0)]
    for pre in pres:
        pre.gyro_heading = True
    for i in range(1, 501):
        t = i / 50.0
        roll, pitch = 0.2 * math.sin(0.7 * t), 0.1 * math.cos(0.4 * t)
        for pre in pres:
            pre.add(ImuSample(t, (0.0, 0.0, -G), (0.01, 0.02, 0.3), roll, pitch, 0.0))
    assert pres[1].tilt is not None and abs(pres[1].tilt[0] - 0.2 * math.sin(0.7 * 10.0)) > 0.05  # it lags
    assert pres[1].theta == pres[0].theta
    assert pres[0].theta != pytest.approx(0.3 - 0.3 * 10.0, abs=1e-3)  # levelling mattered: not r alone
