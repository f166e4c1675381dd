"""FixService (cvgl/service.py): the decoys it asks beside a trigger and the chance level it hands each answer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taco_mav.bench.classical import synthetic_world
from taco_mav.config import ClassicalMatcherConfig, EmulatorConfig, MapConfig
from taco_mav.core.answer_check import log_odds
from taco_mav.core.search import body_to_world, cross_offsets
from taco_mav.core.types import FixQuery, MatchResult
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.classical import ClassicalMatcher
from taco_mav.cvgl.emulator import EmulatorMatcher
from taco_mav.cvgl.service import FixService, chance_levels

GATE = 0.35


def turned(psi: float, w: float) -> MatchResult:
    return MatchResult(np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]]), np.zeros(2), w)


def test_the_chance_level_counts_only_decoys_that_take_the_wrong_heading_somewhere_else() -> None:
    own = [turned(0.0, 0.9), None]
    own_xy = np.array([[0.0, 0.0], [np.nan, np.nan]])
    decoys = [turned(0.1, 0.4), turned(-math.pi / 2, 0.99), None, turned(0.3, 0.2), turned(0.0, 0.95)]
    decoy_xy = np.array([[10.0, 0.0], [10.0, 0.0], [np.nan, np.nan], [0.0, 12.0], [1.0, 1.0]])
    # the 0.99 answer recovered the quarter turn (recognition); the 0.95 one landed on the answer (symmetric
    # ground); the 0.4 one is chance
    assert chance_levels(own, own_xy, decoys, decoy_xy, GATE, 3.0) == [0.4, None]
    assert chance_levels(own, own_xy, decoys, decoy_xy, None, 3.0) == [0.99, None]  # no yaw gate: every turn
    assert chance_levels(own, own_xy, decoys, decoy_xy, GATE, 0.5) == [0.95, None]
    assert chance_levels(own, own_xy, [turned(math.pi, 0.9)], np.array([[5.0, 5.0]]), GATE, 3.0) == [0.0, None]


class Counting:
    """A matcher wrapper that keeps the crops each call was given."""

    def __init__(self, matcher: ClassicalMatcher) -> None:
        self.m, self.name, self.calls = matcher, matcher.name, []

    def match(self, frame, crops):  # type: ignore[no-untyped-def]
        self.calls.append(list(crops))
        return self.m.match(frame, crops)


def test_decoys_ride_with_the_trigger_and_set_the_chance_level_on_a_rendered_world() -> None:
    mcfg = MapConfig()
    with synthetic_world(3, 1500, 0.2) as (renderer, smap, cam):
        E, N, theta = 500_150.0, 5_429_850.0, 0.7
        frame = GroundFrame(renderer.render((E, N, theta)), 0.0, cam)
        spy = Counting(ClassicalMatcher(ClassicalMatcherConfig(), cam))
        offsets = cross_offsets(6.0)
        prior = np.array([E + 4.0, N - 3.0])
        query = FixQuery(1, 0.0, prior, theta, offsets, prior[None, :] + body_to_world(theta, offsets), 0.0)
        plain = FixService(spy, smap, np.zeros(2), mcfg.crop_size_px, mcfg.crop_m_per_px).answer(query, frame)
        service = FixService(spy, smap, np.zeros(2), mcfg.crop_size_px, mcfg.crop_m_per_px, decoys=3,
                             yaw_gate_rad=GATE)
        res = service.answer(query, frame)
    assert [len(c) for c in spy.calls] == [5, 8]
    decoy_crops = spy.calls[1][5:]
    centre = np.mean(query.crop_centres, axis=0)
    for crop, turn in zip(decoy_crops, (math.pi / 2, -math.pi / 2, math.pi)):
        assert np.allclose(crop.centre_utm, centre) and crop.heading == pytest.approx(theta + turn)
    assert len(res) == 5 and all(r is not None and r.null_w is not None for r in res)
    # the trigger's own answers are those without decoys, bit for bit, and far above the chance level
    assert all(np.array_equal(a.t, b.t) and a.w == b.w and b.null_w is None for a, b in zip(res, plain))
    # and they beat it by the rover profiles' margin (4 in log-odds)
    assert min(log_odds(r.w) - log_odds(r.null_w) for r in res) >= 4.0


def test_a_matcher_that_recovers_the_turn_leaves_no_chance_level() -> None:
    truth = (500_000.0, 5_430_000.0, 0.3)
    matcher = EmulatorMatcher(EmulatorConfig(), lambda t: truth, seed=1)
    offsets = cross_offsets(5.0)
    centres = np.array(truth[:2])[None, :] + body_to_world(truth[2], offsets)
    query = FixQuery(1, 0.0, np.array(truth[:2]), truth[2], offsets, centres, 0.0)
    service = FixService(matcher, None, np.zeros(2), decoys=3, yaw_gate_rad=GATE)
    assert service.decoy_turns == ()  # no map, no decoy crops: the emulator on an image-less drive is unchanged
    assert all(r.null_w is None for r in service.answer(query, GroundFrame(np.zeros((0, 0, 3), np.uint8), 0.0,
                                                                            None)))  # type: ignore[arg-type]
