import math

import numpy as np
import pytest
from helpers import OracleMatcher, simulate

from taco_mav.core.localiser import Localiser
from taco_mav.core.params import ImuParams, LocaliserParams
from taco_mav.core.ukf import PlanarUkf, fix_covariance, fix_sigmas, process_noise, process_sigmas

CHI2_2DOF_95 = 5.991


def test_fix_sigmas_inverse_weight_with_clips():
    assert fix_sigmas(1.0) == pytest.approx((1.5, 3.0))
    assert fix_sigmas(0.5) == pytest.approx((3.0, 6.0))
    assert fix_sigmas(0.1) == pytest.approx((8.0, 12.0))  # both capped
    assert fix_sigmas(5.0) == pytest.approx((0.5, 1.0))  # both floored
    assert fix_sigmas(0.2) == pytest.approx((7.5, 12.0))  # fwd inside, lat capped
    assert fix_sigmas(1.0, anisotropic=False) == pytest.approx((2.25, 2.25))


def test_process_sigmas_and_noise_scaling():
    assert process_sigmas(0.2) == pytest.approx((1.0, 1.5))  # floors
    assert process_sigmas(10.0) == pytest.approx((20.0, 3.0))
    Q = process_noise(0.0, 2.0, 1.5, 0.05, dt=0.01, frame_dt=0.1)  # one 100 Hz step = a tenth of a frame
    assert np.diag(Q) == pytest.approx([0.4, 0.225, 0.00025])
    Qn = process_noise(math.pi / 2, 2.0, 1.5, 0.05, dt=0.1, frame_dt=0.1)  # heading north: fwd on y
    assert np.diag(Qn) == pytest.approx([2.25, 4.0, 0.0025])


def test_measurement_covariance_rotates_with_heading():
    assert fix_covariance(0.0, 1.0, 2.0) == pytest.approx(np.diag([1.0, 4.0]))
    assert fix_covariance(math.pi / 2, 1.0, 2.0) == pytest.approx(np.diag([4.0, 1.0]))
    R = fix_covariance(math.radians(45), 1.0, 2.0)
    assert R[0, 1] == pytest.approx(-1.5)  # (1 - 4) / 2 * sin(90 deg)
    assert np.trace(R) == pytest.approx(5.0)


def test_position_update_equals_the_kalman_closed_form():
    f = PlanarUkf(np.array([0.0, 0.0, 0.3]), np.diag([4.0, 9.0, 0.01]))
    nis = f.update_position(np.array([2.0, -3.0]), np.diag([4.0, 9.0]))
    assert f.x[:2] == pytest.approx([1.0, -1.5])  # equal weights: halfway
    assert f.P[0, 0] == pytest.approx(2.0) and f.P[1, 1] == pytest.approx(4.5)
    assert nis == pytest.approx(4.0 / 8.0 + 9.0 / 18.0)


def test_filter_is_never_overconfident_on_a_simulated_drive():
    d = simulate(lambda t: min(9.0, 2.0 + t), lambda t: 0.08 * math.sin(0.05 * t), 240.0,
                 accel_noise=0.05, gyro_noise=0.001, compass_noise=0.01, seed=4)
    loc = Localiser(LocaliserParams(imu=ImuParams(gyro_arw=1e-4)), 0.0, heading=float(d.theta[0]), speed=2.0)
    matcher = OracleMatcher(d, sigma_fwd=1.0, sigma_lat=2.0, seed=5)  # what w = 1 claims is 1.5 / 3.0
    nees = []
    for s in d.samples:
        loc.add_imu(s)
        q = loc.poll_query()
        if q is not None:
            out = loc.add_fix(q.query_id, matcher.answer(q))
            assert out.accepted
            x, y, _ = d.pose_at(q.capture_t)
            e = loc.timeline.ukf.x[:2] - np.array([x, y])
            nees.append(float(e @ np.linalg.solve(loc.timeline.ukf.P[:2, :2], e)))
    assert len(nees) > 80
    inside = np.mean(np.array(nees) <= CHI2_2DOF_95)
    assert inside >= 0.90, f"only {inside:.0%} of fixes inside the 95% chi2 bound"


def test_numerical_soundness_after_ten_minutes_without_a_fix():
    f = PlanarUkf(np.array([0.0, 0.0, 0.0]), np.diag([1e-4, 1e-4, 0.0025]))
    rng = np.random.default_rng(0)
    theta = 0.0
    for k in range(6000):  # 10 min of 10 Hz frames at 8 m/s, paper Q at eps = 5 m
        dth = 0.02 * math.sin(k / 50.0)
        theta += dth
        f.predict(0.8, 0.0, dth, process_noise(theta, 10.0, 1.5, 0.05, 0.1, 0.1))
        f.update_heading(theta + rng.normal(0, 0.02), 0.05)
        assert np.array_equal(f.P, f.P.T)
    assert np.trace(f.P[:2, :2]) > 100.0  # variance in the hundreds of m^2 or more
    # a confident fix collapses it; then keep predicting
    f.update_position(f.x[:2] + np.array([3.0, -2.0]), np.diag([0.25, 1.0]))
    assert np.trace(f.P[:2, :2]) < 1.5
    for _ in range(50):
        f.predict(0.8, 0.0, 0.0, process_noise(theta, 1.0, 1.5, 0.05, 0.1, 0.1))
        f.update_position(f.x[:2] + rng.normal(0, 0.5, 2), np.diag([0.25, 1.0]))
        np.linalg.cholesky(f.P)  # raises if not positive definite
        assert np.array_equal(f.P, f.P.T)
        assert np.all(np.isfinite(f.x)) and np.linalg.eigvalsh(f.P).min() > 0
