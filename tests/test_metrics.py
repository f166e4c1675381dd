import math

import numpy as np
import pytest

from taco_mav.evaluation.metrics import (COVERAGE_GAUSSIAN_RANGE, align_first_pose, along_cross, coverage,
                                         cumulative_distance, fix_errors, h_acc_from_var, path_length_m,
                                         position_errors, rmse, steady_state_rmse, track_errors)


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


def test_errors_split_along_and_across_the_true_heading():
    # heading north (ENU pi/2): an error to the east is to the right (negative cross), to the north is ahead
    assert along_cross(np.array([[1.0, 0.0], [0.0, 2.0]]), np.array([math.pi / 2] * 2)) == pytest.approx(
        np.array([[0.0, -1.0], [2.0, 0.0]]), abs=1e-12)
    # a track that runs 1.5 m ahead and 0.5 m to the left of a curving truth, first poses aligned
    th = np.linspace(0.0, 1.0, 20)
    gt = np.column_stack([np.cumsum(np.cos(th)), np.cumsum(np.sin(th))])
    est = gt + 1.5 * np.column_stack([np.cos(th), np.sin(th)]) + 0.5 * np.column_stack([-np.sin(th), np.cos(th)])
    est[0] = gt[0]
    split = track_errors(est, gt, th, 0.0, 0.0)
    assert split[1:] == pytest.approx(np.tile([1.5, 0.5], (19, 1)), abs=1e-9)
    assert np.hypot(split[:, 0], split[:, 1]) == pytest.approx(position_errors(est, gt, 0.0, 0.0), abs=1e-9)


def test_fix_errors_are_against_the_truth_at_the_capture_time():
    t = np.array([0.0, 1.0, 2.0])
    gt = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    heading = np.array([0.0, 0.0, math.pi / 2])
    # captured at 0.5 s (truth (5, 0), heading east) 0.3 m behind and 0.2 m to the right; at 2 s (heading
    # north) exactly on the truth
    e = fix_errors(np.array([0.5, 2.0]), np.array([[4.7, -0.2], [10.0, 10.0]]), t, gt, heading)
    assert e == pytest.approx(np.array([[-0.3, -0.2], [0.0, 0.0]]), abs=1e-12)
    assert fix_errors(np.array([]), np.zeros((0, 2)), t, gt, heading).shape == (0, 2)


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
    assert 0.85 <= coverage(r, h, 2.0) <= 0.98  # the target band (docs/evaluation.md) holds for any calibrated shape
    assert coverage(r, 2.0 * h, 2.0) > 0.98 and coverage(r, 0.5 * h, 2.0) < 0.85  # and flags a factor 2 either way
