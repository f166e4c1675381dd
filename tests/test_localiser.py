
import numpy as np
import pytest
from helpers import OracleMatcher, simulate

from taco_mav.core.localiser import Localiser
from taco_mav.core.params import ImuParams, LatencyParams, LocaliserParams, TriggerParams
from taco_mav.core.types import MatchResult


def _drive(seed: int = 1):
    return simulate(lambda t: min(10.0, 1.0 + t), lambda t: 0.1 if 30 < t < 45 else (-0.05 if 80 < t < 100 else 0.0),
                    150.0, accel_noise=0.05, gyro_noise=0.001, compass_noise=0.01, seed=seed)


def run(drive, params: LocaliserParams, latency: float = 0.0, matcher=None, planted=None):
    """Feed the drive; deliver each query's answer `latency` seconds after capture. Returns (loc, ate)."""
    loc = Localiser(params, 0.0, heading=float(drive.theta[0]), speed=float(drive.speed[0]))
    matcher = matcher or OracleMatcher(drive, seed=2)
    pending = []
    for s in drive.samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            pending.append((q.capture_t + latency, q))
        while pending and pending[0][0] <= s.t + 1e-9:
            _, q = pending.pop(0)
            answer = planted(q) if planted else matcher.answer(q)
            loc.add_fix(q.query_id, answer)
    track = np.array(loc.record.track)
    truth = np.array([drive.pose_at(t)[:2] for t in track[:, 0]])
    ate = float(np.sqrt(np.mean(np.sum((track[:, 1:3] - truth) ** 2, axis=1))))
    return loc, ate


def test_delayed_fixes_are_compensated_and_naive_application_is_worse():
    d = _drive()
    _, ate0 = run(d, LocaliserParams())
    _, ate03 = run(d, LocaliserParams(), latency=0.3)
    _, ate1 = run(d, LocaliserParams(), latency=1.0)
    _, naive1 = run(d, LocaliserParams(latency=LatencyParams(apply_on_arrival=True)), latency=1.0)
    assert ate0 < 1.5
    assert abs(ate03 - ate0) <= 0.5
    assert abs(ate1 - ate0) <= 0.5
    assert naive1 > ate0 + 3.0  # ~10 m/s x 1 s stale


def test_time_trigger_fires_on_a_stationary_vehicle():
    d = simulate(lambda t: 0.0, lambda t: 0.0, 7.0)
    loc = Localiser(LocaliserParams(), 0.0, heading=0.0, speed=0.0)
    queries = []
    for s in d.samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            queries.append(q)
            loc.add_fix(q.query_id, [MatchResult(np.array([[1.0, 0.0], [0.0, 1.0]]), np.zeros(2), 1.0)] * 5)
    assert [q.reason for q in queries] == ["time", "time", "time"]
    assert [round(q.capture_t, 2) for q in queries] == [2.0, 4.0, 6.0]
    assert queries[0].epsilon == pytest.approx(0.0)
    assert np.ptp(queries[0].crop_centres, axis=0) == pytest.approx([0.0, 0.0])  # eps = 0: a collapsed cross


def test_error_trigger_fires_on_a_moving_vehicle_before_the_time_trigger():
    d = simulate(lambda t: 10.0, lambda t: 0.0, 3.0)
    loc = Localiser(LocaliserParams(imu=ImuParams(gyro_arw=0.05)), 0.0, heading=0.0, speed=10.0)
    q = None
    for s in d.samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            break
    # eps_cross = 3 (10 T) 0.05 sqrt(T) >= 1 m  <=>  T >= 0.763 s: the first frame after is 0.8 s
    assert q is not None and q.reason == "error"
    assert q.capture_t == pytest.approx(0.8, abs=1e-6)
    assert q.epsilon == pytest.approx(1.5 * 0.8**1.5, rel=1e-3)
    # forward bias 0.4 eps along heading east from the UKF position, cross arm 0.5 eps
    assert q.centre - loc.timeline.ukf.x[:2] == pytest.approx([0.4 * q.epsilon, 0.0], abs=1e-9)
    assert loc.timeline.ukf.x[0] == pytest.approx(8.0, abs=0.02)  # the unscented mean is E[cos(theta)] short
    assert q.crop_centres[2] - q.centre == pytest.approx([0.5 * q.epsilon, 0.0], abs=1e-6)


def test_yaw_gate_rejects_and_resets_the_time_counter_only():
    d = simulate(lambda t: 0.0, lambda t: 0.0, 5.0)
    loc = Localiser(LocaliserParams(), 0.0)
    bad = [MatchResult(np.array([[0.0, -1.0], [1.0, 0.0]]), np.array([30.0, 0.0]), 1.0)] * 5
    outcomes = []
    for s in d.samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            outcomes.append(loc.add_fix(q.query_id, bad))
    assert [o.reason for o in outcomes] == ["yaw_gate", "yaw_gate"]  # at 2 s and 4 s, not every frame
    assert np.linalg.norm(loc.estimate().xy) < 0.1  # the 30 m fix never entered the filter


def test_single_crop_and_no_forward_bias_switches_change_the_query():
    d = simulate(lambda t: 10.0, lambda t: 0.0, 3.0)
    imu = ImuParams(gyro_arw=0.05)
    for params, n_crops, biased in [(LocaliserParams(imu=imu), 5, True),
                                     (LocaliserParams(imu=imu, trigger=TriggerParams(multi_crop=False)), 1, True),
                                     (LocaliserParams(imu=imu, trigger=TriggerParams(forward_bias=False)), 5, False)]:
        loc = Localiser(params, 0.0, speed=10.0)
        q = None
        for s in d.samples:
            loc.add_imu(s)
            q = q or loc.poll_query()
        assert len(q.crop_centres) == n_crops
        assert bool(q.centre[0] > 8.0 + 1e-6) is biased


def test_estimate_is_finite_and_covariance_grows_without_fixes():
    d = simulate(lambda t: 8.0, lambda t: 0.02, 60.0)
    loc = Localiser(LocaliserParams(), 0.0, speed=8.0)
    sig = []
    for s in d.samples:
        loc.add_imu(s)
        loc.poll_query()  # asked, never answered: times out and is asked again
        if int(s.t * 100) % 500 == 0:
            sig.append(loc.estimate().sigma_h)
    e = loc.estimate()
    assert np.all(np.isfinite(e.xy)) and np.all(np.diff(sig) >= 0)
    assert e.sigma_h > 10.0
    assert np.linalg.norm(e.xy - d.xy[-1]) < 1.0  # noise-free IMU: dead reckoning is exact


def test_smoothed_trajectory_is_close_to_truth():
    d = _drive()
    loc, ate = run(d, LocaliserParams())
    res = loc.smoothed()
    track = np.array(loc.record.track)
    truth = np.array([d.pose_at(t)[:2] for t in track[:, 0]])
    smoothed_ate = float(np.sqrt(np.mean(np.sum((res.poses[:, :2] - truth) ** 2, axis=1))))
    assert len(res.poses) == len(track)
    assert smoothed_ate < ate + 0.3
