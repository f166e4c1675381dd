import math

import numpy as np
import pytest

from taco_mav.evaluation.export import read_tum, write_kitti, write_tum


def test_tum_round_trip_and_kitti_rows(tmp_path):
    t = np.array([0.0, 0.1, 0.2])
    xy = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 1.5]])
    th = np.array([0.0, 0.4, -2.9])
    write_tum(tmp_path / "a.tum", t, xy, th)
    t2, xy2, th2 = read_tum(tmp_path / "a.tum")
    assert t2 == pytest.approx(t) and xy2 == pytest.approx(xy, abs=1e-6) and th2 == pytest.approx(th, abs=1e-8)
    write_kitti(tmp_path / "a.kitti", xy, th)
    rows = np.loadtxt(tmp_path / "a.kitti")
    assert rows.shape == (3, 12)
    assert rows[1, 3] == pytest.approx(1.0) and rows[1, 7] == pytest.approx(0.5)
    assert rows[2, 0] == pytest.approx(math.cos(-2.9)) and rows[2, 4] == pytest.approx(math.sin(-2.9))
