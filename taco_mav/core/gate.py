"""Yaw-residual gate (paper Sec. III-E): reject fixes whose rotation disagrees with the compass."""

from __future__ import annotations

import math

import numpy as np


def yaw_residual(R: np.ndarray) -> float:
    """psi_res = atan2(R[1,0], R[0,0]), radians, from a 2x2 residual rotation."""
    return math.atan2(float(R[1, 0]), float(R[0, 0]))


def passes_yaw_gate(R: np.ndarray, max_rad: float = 0.35) -> bool:
    """True when |psi_res| <= max_rad (0.35 rad is accepted, anything beyond it rejected)."""
    return abs(yaw_residual(R)) <= max_rad
