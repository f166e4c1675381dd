import math

import numpy as np
import pytest

from taco_mav.core.gate import passes_yaw_gate, yaw_residual


def rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def test_gate_edge():
    assert passes_yaw_gate(rot(0.35))
    assert passes_yaw_gate(rot(-0.35))
    assert not passes_yaw_gate(rot(0.36))
    assert not passes_yaw_gate(rot(-0.36))
    assert not passes_yaw_gate(rot(math.pi / 2))  # a 90-degree symmetric lock
    assert not passes_yaw_gate(rot(math.pi))


def test_yaw_residual_is_atan2_r10_r00():
    assert yaw_residual(rot(0.2)) == pytest.approx(0.2)
    assert yaw_residual(np.array([[0.0, -1.0], [1.0, 0.0]])) == pytest.approx(math.pi / 2)
