"""The answer check (core/answer_check.py): an answer is credible when it beats its trigger's decoys by the margin
in log-odds, and supported when enough of the trigger's crops give it; the paper's defaults check nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taco_mav.core.answer_check import credible, log_odds, supported
from taco_mav.core.params import AnswerParams
from taco_mav.core.types import MatchResult

ON = AnswerParams(decoys=3, decoy_margin=4.0, min_agree_share=0.5)


def answer(w: float, null_w: float | None = None) -> MatchResult:
    return MatchResult(np.eye(2), np.zeros(2), w, null_w=null_w)


def test_log_odds_is_the_logit_and_clips_at_the_ends() -> None:
    assert log_odds(0.5) == 0.0
    assert log_odds(0.9) == pytest.approx(math.log(9.0))
    assert log_odds(1.0) == pytest.approx(27.63, abs=0.01) and log_odds(0.0) == pytest.approx(-27.63, abs=0.01)


def test_an_answer_must_beat_the_chance_level_by_the_margin() -> None:
    # w 0.94 over a chance level of 0.08 (the real pairs' most confident wrong answer): 2.75 - (-2.44) = 5.2 > 4
    # passes the margin alone; w 0.6 over 0.3: 0.41 - (-0.85) = 1.25 < 4 does not
    res = [answer(0.94, 0.08), answer(0.6, 0.3), answer(0.999, 0.3), None, answer(float("nan"), 0.0)]
    assert credible(res, ON).tolist() == [True, False, True, False, False]
    # a chance level of 0 (every decoy recovered its turn, as a matcher that searches all rotations does): credible
    assert credible([answer(0.3, 0.0)], ON).tolist() == [True]


def test_the_paper_defaults_take_every_finite_answer() -> None:
    paper = AnswerParams()
    res = [answer(0.01, 0.9), answer(0.5), None, answer(float("nan"))]
    assert credible(res, paper).tolist() == [True, True, False, False]
    xy = np.array([[0.0, 0.0], [50.0, 0.0]])
    assert supported(xy, 0, xy, paper)


def test_w_min_alone() -> None:
    p = AnswerParams(w_min=0.5)
    assert credible([answer(0.49), answer(0.5)], p).tolist() == [False, True]


CROSS = np.array([[-9.0, 0.0], [0.0, 0.0], [9.0, 0.0], [0.0, 9.0], [0.0, -9.0]])  # back, centre, fwd, left, right


def test_support_counts_the_answers_near_the_chosen_one_among_the_crops_that_could_give_it() -> None:
    xy = np.array([[0.0, 0.0], [1.0, 1.0], [2.5, 0.0], [20.0, 0.0], [np.nan, np.nan]])
    assert supported(xy, 0, CROSS, ON)  # 3 of the 4 answered crops within 20 m agree: a majority
    xy2 = xy.copy()
    xy2[1:3] = [[-12.0, 5.0], [14.0, -6.0]]
    assert not supported(xy2, 0, CROSS, ON)  # alone among four: the crop's own peak
    # an answer 30 m off: only the forward crop's centre lies within 20 m of it, and one crop is never enough
    far = np.array([[30.0, 0.0], [30.5, 0.0], [30.0, 0.5], [30.2, 0.2], [30.1, 0.0]])
    assert not supported(far, 2, CROSS, ON)
    assert supported(xy[:1], 0, CROSS[:1], ON)  # a single-crop trigger: itself


def test_in_a_recovery_grid_only_the_nearby_crops_are_asked_to_agree() -> None:
    # taco+'s hexagonal grid, 15 m spacing: an answer near one edge is seen by the crops within 20 m only
    ring = [(15.0 * math.cos(a), 15.0 * math.sin(a)) for a in np.arange(6) * math.pi / 3]
    ring2 = [(30.0 * math.cos(a), 30.0 * math.sin(a)) for a in np.arange(6) * math.pi / 3]
    centres = np.array([(0.0, 0.0)] + ring + ring2)
    truth = np.array([22.0, 2.0])
    near = np.linalg.norm(centres - truth, axis=1) <= 20.0
    xy = np.where(near[:, None], truth + 0.3, np.array([-40.0, 0.0]) + np.arange(13)[:, None])
    k = int(np.flatnonzero(near)[0])
    assert near.sum() == 3 and supported(xy, k, centres, ON)  # 3 of 3 that could see it; 10 others could not
    alone = np.where((np.arange(13) == k)[:, None], xy, np.array([-40.0, 0.0]) + np.arange(13)[:, None])
    assert not supported(alone, k, centres, ON)  # alone of the three: not enough
