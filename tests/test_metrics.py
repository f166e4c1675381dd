import math

import numpy as np
import pytest

from taco_mav.evaluation.metrics import (COVERAGE_GAUSSIAN_RANGE, align_first_pose, coverage, cumulative_distance,
                                         h_acc_from_var, path_length_m, position_errors, rmse, steady_state_rmse)


def test_first_pose_alignment_removes_a_rigid_offset():
    gt = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 5.0]])
    a = math.radians(20)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    est = gt @ R.T + np.array([100.0, -50.0])
    aligned = align_first_pose(est, a, gt, 0.0)
    assert aligned == pytest.approx(gt, abs=1e-9)
    assert position_errors(est, gt, a, 0.0) == pytest.approx(np.zeros(3), abs=1e-9)


def test_rmse_and_lengths():
    assert rmse(np.array([3.0, 4.0])) == pytest.approx(math.sqrt(12.5))
    assert rmse(np.array([])) == 0.0
    xy = np.array([[0, 0], [3, 4], [3, 10]], dtype=float)
    assert path_length_m(xy) == pytest.approx(11.0)
    assert cumulative_distance(xy) == pytest.approx([0.0, 5.0, 11.0])


def test_steady_state_starts_at_the_third_accepted_fix():
    t = np.arange(10.0)
    e = np.array([9, 9, 9, 9, 9, 1, 1, 1, 1, 1], dtype=float)
    assert steady_state_rmse(e, t, [1.0, 3.0, 5.0, 7.0]) == pytest.approx(1.0)
    assert math.isnan(steady_state_rmse(e, t, [1.0, 3.0]))


def test_h_acc_is_the_per_axis_sigma_of_the_worst_direction():
    # diag(4, 1) rotated by 30 degrees: eigenvalues 4 and 1, whatever the rotation
    a = math.radians(30)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    P = R @ np.diag([4.0, 1.0]) @ R.T
    var = np.array([[P[0, 0], P[0, 1], P[1, 1]], [0.25, 0.0, 0.25]])
    assert h_acc_from_var(var) == pytest.approx([2.0, 0.5])


def test_coverage_counts_radial_errors_within_k_h_acc():
    err = np.array([0.5, 1.0, 1.5, 2.5, 4.0])
    h = np.ones(5)
    assert coverage(err, h, 1.0) == pytest.approx(2 / 5)  # 0.5 and 1.0 (the boundary counts)
    assert coverage(err, h, 2.0) == pytest.approx(3 / 5)
    assert coverage(err, np.array([1.0, 1.0, np.nan, 1.0, np.inf]), 2.0) == pytest.approx(2 / 5)  # nan, inf: nothing
    assert math.isnan(coverage(np.array([]), np.array([]), 1.0))
    with pytest.raises(ValueError):
        coverage(err, np.ones(4), 1.0)


@pytest.mark.parametrize("ratio", [1.0, 0.01])
def test_calibrated_gaussian_errors_fall_in_the_documented_coverage_bands(ratio):
    # isotropic (ratio 1) and nearly one-dimensional (0.01) Gaussian errors with the reported covariance
    rng = np.random.default_rng(7)
    n = 200_000
    P = np.diag([1.0, ratio])
    e = rng.multivariate_normal(np.zeros(2), P, size=n)
    h = h_acc_from_var(np.tile([P[0, 0], P[0, 1], P[1, 1]], (n, 1)))
    r = np.linalg.norm(e, axis=1)
    for k, (lo, hi) in COVERAGE_GAUSSIAN_RANGE.items():
        c = coverage(r, h, float(k))
        expected = lo if ratio == 1.0 else hi
        assert c == pytest.approx(expected, abs=0.01)
    assert 0.85 <= coverage(r, h, 2.0) <= 0.98  # the band holds for any calibrated shape
    assert coverage(r, 2.0 * h, 2.0) > 0.98 and coverage(r, 0.5 * h, 2.0) < 0.85  # and flags a factor 2 either way
