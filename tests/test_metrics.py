import math

import numpy as np
import pytest

from taco_mav.evaluation.metrics import (align_first_pose, cumulative_distance, path_length_m, position_errors, rmse,
                                         steady_state_rmse)


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
