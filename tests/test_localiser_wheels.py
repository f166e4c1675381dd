"""taco+ with wheel encoders (core/plus/wheel_speed.py, wheel_scale.py) on a simulated rover drive with the
camera's fixes from an oracle: fewer fixes per km at equal or better accuracy, a wrong wheel radius learnt from
the fixes, and nothing changed without wheels or in paper mode."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers import OracleMatcher, SimDrive, simulate, wheel_distances

from taco_mav.core.localiser import make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.wheel_odometry import WheelOdometry
from taco_mav.core.wheel_params import WheelParams

POS_Y = (0.15, -0.15)
# the rover profile's taco+ (vehicle_profiles/ardupilot_rover.yaml): a MEMS IMU's fast speed drift, fixes every 5 s
ROVER = LocaliserParams(plus=PlusParams(q_speed_mps=0.5, trigger_sigma_m=4.5, trigger_time_s=5.0,
                                        compass_bias_sigma_rad=0.03))
WHEELS = dataclasses.replace(ROVER, wheels=WheelParams(enabled=True, wheel_pos_y_m=POS_Y))


def rover_drive(duration: float = 300.0, seed: int = 3) -> SimDrive:
    """A rover at about 3 m/s with gentle speed changes and turns, 50 Hz MEMS-like IMU."""
    return simulate(lambda t: min(3.0, 0.5 + t) + 0.3 * math.sin(t / 7.0), lambda t: 0.08 * math.sin(t / 11.0),
                    duration, rate_hz=50.0, accel_noise=0.05, gyro_noise=0.001, compass_noise=0.005, seed=seed)


@dataclasses.dataclass
class WheelRun:
    fixes_per_km: float
    rms_m: float
    loc: object
    speed_err: list[tuple[int, float]]  # (accepted fixes so far, |speed - true| m/s) at every 0.1 s
    scales: list[float]  # the wheels' learnt scale after each accepted fix (empty without wheels)


def run(d: SimDrive, params: LocaliserParams, wheels: bool, radius_ratio: float = 1.0, rate_hz: float = 20.0,
        latency_s: float = 0.3) -> WheelRun:
    """Drive `d` with oracle fixes (0.5 m, answered latency_s late) and, with `wheels`, WHEEL_DISTANCE at rate_hz
    (whole milliseconds, as ArduPilot stamps it)."""
    m = OracleMatcher(d, sigma_fwd=0.5, sigma_lat=0.5, seed=1)
    loc = make_localiser(params, 0.0, heading=float(d.theta[0]), speed=float(d.speed[0]))
    odo = WheelOdometry(POS_Y, 20.0)
    dist = wheel_distances(d, POS_Y, radius_ratio)
    next_w, pending, err, speed_err, scales = 0.0, [], [], [], []
    for k, s in enumerate(d.samples):
        loc.add_imu(s)
        if wheels and s.t >= next_w - 1e-9:
            next_w += 1.0 / rate_hz
            w = odo.add(math.floor(s.t * 1000.0) / 1000.0, dist[k])
            if not isinstance(w, str):
                loc.aids.add_wheel_speed(w)
        q = loc.poll_query()
        if q is not None:
            pending.append((q.capture_t + latency_s, q))
        while pending and pending[0][0] <= s.t + 1e-9:
            _, q = pending.pop(0)
            if loc.add_fix(q.query_id, m.answer(q)).accepted and loc.aids.wheels is not None:
                scales.append(loc.aids.wheels.scale.s)
        if k % 5 == 0:
            est = loc.estimate()
            err.append(float(np.linalg.norm(est.xy - np.array(d.pose_at(s.t)[:2]))))
            fixes = sum(o.accepted for o in loc.record.outcomes)
            speed_err.append((fixes, abs(est.speed - float(d.speed[k]))))
    accepted = sum(o.accepted for o in loc.record.outcomes)
    return WheelRun(accepted / (d.length / 1000.0), float(np.sqrt(np.mean(np.square(err)))), loc, speed_err, scales)


@pytest.fixture(scope="module")
def drive() -> SimDrive:
    return rover_drive()


@pytest.fixture(scope="module")
def without(drive: SimDrive) -> WheelRun:
    return run(drive, ROVER, wheels=False)


def test_wheels_take_fewer_fixes_per_km_at_equal_or_better_accuracy(drive: SimDrive, without: WheelRun) -> None:
    with_wheels = run(drive, WHEELS, wheels=True)
    # 0.9 km: 68 fixes/km at 0.89 m RMS on the IMU's speed; 16 fixes/km at 0.67 m RMS on the wheels'
    assert without.fixes_per_km > 60.0 and with_wheels.fixes_per_km < 20.0
    assert with_wheels.rms_m <= without.rms_m
    assert with_wheels.loc.estimate().extra["wheels_refused"] is None


def test_a_wheel_radius_5_percent_wrong_is_learnt_from_the_fixes(drive: SimDrive, without: WheelRun) -> None:
    r = run(drive, WHEELS, wheels=True, radius_ratio=1.05)
    true = 1 / 1.05
    # the speed error the scale leaves at 3.3 m/s after each fix: 0.036, 0.027, 0.019 m/s ... (0.16 before any)
    assert [round(3.3 * abs(s - true), 3) for s in r.scales[:3]] == pytest.approx([0.036, 0.027, 0.019], abs=0.01)
    assert all(3.3 * abs(s - true) < 0.05 for s in r.scales) and len(r.scales) >= 10
    after = np.array([e for n, e in r.speed_err if n >= 2])  # the estimate's speed from the second fix on
    assert np.percentile(after, 95) < 0.05 and np.median(after) < 0.02
    assert r.rms_m <= without.rms_m and r.fixes_per_km < 20.0


def test_without_wheels_in_the_parameters_the_wheel_entry_changes_nothing(drive: SimDrive) -> None:
    short = SimDrive(drive.t[:1500], drive.xy[:1500], drive.theta[:1500], drive.speed[:1500], drive.samples[:1500])
    plain = run(short, ROVER, wheels=False)
    loc = make_localiser(ROVER, 0.0, heading=float(short.theta[0]), speed=float(short.speed[0]))
    assert loc.aids.wheels is None and loc.aids.wheels_refused() is None
    odo = WheelOdometry(POS_Y, 20.0)
    odo.add(0.0, (0.0, 0.0))
    assert loc.aids.add_wheel_speed(odo.add(0.05, (0.1, 0.1))) == "off"
    assert "wheel_scale" not in plain.loc.estimate().extra


def test_paper_mode_has_no_wheel_entry() -> None:
    paper = dataclasses.replace(WHEELS, plus=None)
    assert make_localiser(paper, 0.0).aids is None
