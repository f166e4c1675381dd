"""The survey verdict (daemon/survey.py): camera fixes usable here or not, for the drive and stretch by stretch."""

from __future__ import annotations

import math

import numpy as np

from taco_mav.daemon.survey import SurveyAnswer, stretches, verdict


def answers(odo: np.ndarray, accepted: np.ndarray, error: np.ndarray) -> list[SurveyAnswer]:
    rows = enumerate(zip(odo, accepted, error))
    return [SurveyAnswer(float(i), float(o), bool(a), float(e)) for i, (o, a, e) in rows]


def test_a_camera_that_fixes_often_and_right_is_usable() -> None:
    a = answers(np.arange(10) * 15.0, np.array([1, 0, 1, 1, 0, 1, 0, 1, 1, 0]), np.full(10, 0.4))
    v = verdict(a)
    assert (v.verdict, v.answers, v.accepted, v.precision, v.median_error_m) == ("usable", 10, 6, 1.0, 0.4)
    assert v.line() == ("camera fixes usable here: 6 of 10 answers accepted, 100% within 3 m of the receiver "
                        "(median 0.40 m)")


def test_one_wrong_fix_in_twenty_or_too_few_fixes_is_not_usable() -> None:
    err = np.full(20, 0.5)
    err[7] = 18.0  # one accepted fix 18 m off: precision 0.95 is the least allowed
    assert verdict(answers(np.arange(20.0), np.ones(20, bool), err)).verdict == "usable"
    err[8] = 25.0
    v = verdict(answers(np.arange(20.0), np.ones(20, bool), err))
    assert v.verdict == "not usable" and v.precision == 0.9
    few = verdict(answers(np.arange(10.0), np.array([1] * 2 + [0] * 8, bool), np.full(10, 0.3)))
    assert few.verdict == "not usable" and few.accepted_share == 0.2  # right, but a fix every five answers
    # accepted with no receiver to compare: no precision, so not usable
    assert verdict(answers(np.arange(6.0), np.ones(6, bool), np.full(6, math.nan))).verdict == "not usable"
    assert verdict(answers(np.arange(4.0), np.ones(4, bool), np.zeros(4))).verdict == "too few answers"


def test_stretches_split_the_drive_by_distance() -> None:
    odo = np.arange(30) * 15.0  # 0 .. 435 m driven
    acc = odo < 200.0  # the camera reads the first 200 m, then nothing is accepted
    out = stretches(answers(odo, acc, np.full(30, 0.5)), 200.0)
    assert [(s.start_m, s.end_m, s.answers, s.verdict) for s in out] == [
        (0.0, 200.0, 14, "usable"), (200.0, 400.0, 13, "not usable"), (400.0, 600.0, 3, "too few answers")]
    assert out[0].as_dict()["accepted_share"] == 1.0 and stretches([]) == []
