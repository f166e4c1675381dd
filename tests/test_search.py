import math

import numpy as np
import pytest

from taco_mav.core.search import (TriggerReason, best_candidate, body_to_world, cross_offsets, cross_spacing,
                                  fix_position, forward_bias, search_centres, trigger_reason)
from taco_mav.core.types import MatchResult


def test_dual_trigger_branches():
    assert trigger_reason(1.0, 0.1) is TriggerReason.ERROR
    assert trigger_reason(0.99, 1.99) is None
    assert trigger_reason(0.0, 2.0) is TriggerReason.TIME
    assert trigger_reason(5.0, 5.0) is TriggerReason.ERROR


def test_forward_bias_and_cross_arm_with_caps():
    assert forward_bias(10.0) == pytest.approx(4.0)
    assert forward_bias(37.5) == pytest.approx(15.0)
    assert forward_bias(100.0) == 15.0
    assert cross_spacing(1.0) == pytest.approx(0.5)
    assert cross_spacing(20.0) == pytest.approx(10.0)
    assert cross_spacing(28.0) == 10.0


def test_five_point_cross_in_world_for_a_heading_of_30_degrees():
    th = math.radians(30.0)
    eps = 10.0
    offsets = cross_offsets(cross_spacing(eps))
    centre, crops = search_centres(np.array([100.0, 50.0]), th, forward_bias(eps), offsets)
    c, s = math.cos(th), math.sin(th)
    assert centre == pytest.approx([100 + 4 * c, 50 + 4 * s])
    expected = {
        "back": centre - 5 * np.array([c, s]),
        "centre": centre,
        "forward": centre + 5 * np.array([c, s]),
        "left": centre + 5 * np.array([-s, c]),
        "right": centre - 5 * np.array([-s, c]),
    }
    for k, name in enumerate(["back", "centre", "forward", "left", "right"]):
        assert crops[k] == pytest.approx(expected[name])
    assert cross_offsets(5.0, multi_crop=False).shape == (1, 2)


def test_fix_position_rotates_the_crop_answer_by_heading():
    # heading north: forward = +N, left = -E
    assert fix_position(np.array([100.0, 200.0]), math.pi / 2, np.array([3.0, 1.0])) == pytest.approx([99.0, 203.0])
    assert fix_position(np.array([0.0, 0.0]), 0.0, np.array([3.0, 1.0])) == pytest.approx([3.0, 1.0])
    assert body_to_world(math.pi, np.array([1.0, 0.0])) == pytest.approx([-1.0, 0.0])


def test_best_candidate_is_the_largest_weight():
    I = np.eye(2)
    rs = [MatchResult(I, np.zeros(2), w) for w in (0.2, 0.9, 0.5, 0.9, 0.1)]
    assert best_candidate(rs) == 1
    with pytest.raises(ValueError):
        best_candidate([])


@pytest.mark.parametrize("heading_deg", [0.0, 30.0, 90.0, 180.0, -135.0])
def test_fix_position_takes_the_camera_lever_arm_off(heading_deg):
    """The matcher's t is the camera's position; with the camera 1.08 m ahead of and 0.25 m right of the reference
    point (FRD [1.08, 0.25, z] -> (forward, left) (1.08, -0.25)) the fix is the reference point, at any heading."""
    th = math.radians(heading_deg)
    ref = np.array([500.0, -20.0])
    lever = np.array([1.08, -0.25])
    camera = ref + body_to_world(th, lever)  # where the camera truly is
    centre = ref + body_to_world(th, np.array([4.0, 2.0]))  # a crop 4 m ahead, 2 m left of the vehicle
    c, s = math.cos(th), math.sin(th)
    d = camera - centre
    t = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])  # the camera in the heading-up crop
    assert fix_position(centre, th, t, lever) == pytest.approx(ref, abs=1e-12)
    assert fix_position(centre, th, t) == pytest.approx(camera, abs=1e-12)  # no lever arm: the camera's position
    assert np.linalg.norm(fix_position(centre, th, t) - ref) == pytest.approx(math.hypot(1.08, 0.25))
    # east heading, numbers by hand: the camera is 1.08 m east and 0.25 m south of the reference point
    assert fix_position([0.0, 0.0], 0.0, [1.08, -0.25], lever) == pytest.approx([0.0, 0.0])
    assert fix_position([0.0, 0.0], math.pi / 2, [0.0, 0.0], lever) == pytest.approx([-0.25, -1.08])
