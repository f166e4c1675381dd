"""Dual trigger, forward bias and the five-point cross search (paper Sec. III-D), and the one place where a
matcher's crop-frame answer becomes a world fix.

Body-frame offsets are (forward, left) metres; world positions are ENU metres; heading theta is ENU radians.
"""

from __future__ import annotations

import math
from enum import Enum
from typing import Sequence

import numpy as np

from taco_mav.core.types import MatchResult


class TriggerReason(Enum):
    """Why a fix was requested."""

    ERROR = "error"  # eps_IMU >= threshold (moving regime)
    TIME = "time"  # time since the last fix >= threshold (stationary regime)


def trigger_reason(epsilon: float, since_fix_s: float, epsilon_m: float = 1.0, time_s: float = 2.0) -> TriggerReason | None:
    """The dual trigger: ERROR when eps_IMU >= epsilon_m, else TIME when since_fix_s >= time_s, else None."""
    if epsilon >= epsilon_m:
        return TriggerReason.ERROR
    if since_fix_s >= time_s:
        return TriggerReason.TIME
    return None


def forward_bias(epsilon: float, k: float = 0.4, cap_m: float = 15.0) -> float:
    """delta_fwd = min(k eps, cap), metres along the heading."""
    return min(k * epsilon, cap_m)


def cross_spacing(epsilon: float, k: float = 0.5, cap_m: float = 10.0) -> float:
    """d = min(k eps, cap), metres: the arm of the five-point cross."""
    return min(k * epsilon, cap_m)


def cross_offsets(d: float, multi_crop: bool = True) -> np.ndarray:
    """Body-frame (forward, left) offsets, metres, shape (5, 2): back, centre, forward, left, right; or only
    the centre, shape (1, 2), for the single-crop ablation."""
    if not multi_crop:
        return np.zeros((1, 2))
    return np.array([[-d, 0.0], [0.0, 0.0], [d, 0.0], [0.0, d], [0.0, -d]])


def body_to_world(heading: float, fwd_left: np.ndarray) -> np.ndarray:
    """Rotate body (forward, left) vectors, shape (..., 2), into ENU by heading theta (rad)."""
    c, s = math.cos(heading), math.sin(heading)
    v = np.asarray(fwd_left, dtype=float)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def search_centres(xy: np.ndarray, heading: float, bias_m: float, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The forward-biased search centre and the crop centres, ENU metres: (2,), (K, 2)."""
    centre = np.asarray(xy, dtype=float) + body_to_world(heading, np.array([bias_m, 0.0]))
    return centre, centre + body_to_world(heading, offsets)


def fix_position(crop_centre: np.ndarray, heading: float, t_fwd_left: np.ndarray,
                 lever_fwd_left: np.ndarray | tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """World position of a fix, ENU metres: the VEHICLE REFERENCE POINT. The matcher's (forward, left) answer t
    is the camera's ground position in the heading-up crop (cvgl/base.py); lever_fwd_left is the camera's offset
    from the reference point, body (forward, left) metres (profile camera.position_frd_m [x, y] as (x, -y)). So
    fix = crop centre + R(heading) (t - lever), heading the crop's (ENU rad). The only conversion from a
    crop-frame answer to the world, for every matcher."""
    t = np.asarray(t_fwd_left, dtype=float) - np.asarray(lever_fwd_left, dtype=float)
    return np.asarray(crop_centre, dtype=float) + body_to_world(heading, t)


def best_candidate(results: Sequence[MatchResult]) -> int:
    """Index of the candidate with the largest weight w (paper: the highest-weight crop wins); ties keep the
    first (the back/centre order of `cross_offsets`)."""
    if not results:
        raise ValueError("no match results")
    return int(np.argmax([r.w for r in results]))
