"""FixPipeline's answer hold (`matcher_latency_s`): answers wait on the autopilot clock, in order, and an
answer of an older estimator generation never holds back the ones after it."""

from __future__ import annotations

import numpy as np

from taco_mav.config import profile_from_dict
from taco_mav.core.types import FixQuery
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.options import DaemonOptions
from taco_mav.daemon.worker import WorkResult
from taco_mav.mavlink.timesync import ClockMap
from tests.fault_helpers import Counters


def _answer(query_id: int, capture_t: float, generation: int) -> WorkResult:
    q = FixQuery(query_id, capture_t, np.zeros(2), 0.0, np.zeros((1, 2)), np.zeros((1, 2)), 5.0)
    return WorkResult(q, [], None, capture_t, 0.01, generation)


def _pipeline(latency_s: float) -> FixPipeline:
    opts = DaemonOptions(connect="udpin:127.0.0.1:1", matcher_latency_s=latency_s)
    return FixPipeline(profile=profile_from_dict({"matcher": "emulator"}), options=opts, clockmap=ClockMap(),
                       stats=Counters(), status=lambda sev, text, key: None)


def test_answers_held_on_the_autopilot_clock() -> None:
    pipe = _pipeline(0.3)
    pipe._results.put(_answer(1, 10.0, 0))
    pipe._results.put(_answer(2, 10.2, 0))
    assert pipe._due(10.29, 0) == []
    assert [r.query.query_id for r in pipe._due(10.3, 0)] == [1]
    assert [r.query.query_id for r in pipe._due(10.6, 0)] == [2]
    assert pipe._due(99.0, 0) == []


def test_no_hold_without_latency() -> None:
    pipe = _pipeline(0.0)
    pipe._results.put(_answer(1, 10.0, 0))
    assert [r.query.query_id for r in pipe._due(0.0, 0)] == [1]


def test_older_generation_does_not_block_after_reboot() -> None:
    """After a reboot the clock restarts near 0: the old-clock answer (capture 500 s) comes out at once for the
    caller to drop, and the new generation's answer is held only by its own capture time."""
    pipe = _pipeline(0.3)
    pipe._results.put(_answer(1, 500.0, 0))
    pipe._results.put(_answer(2, 1.0, 1))
    assert [(r.query.query_id, r.generation) for r in pipe._due(1.1, 1)] == [(1, 0)]
    assert [r.query.query_id for r in pipe._due(1.3, 1)] == [2]
