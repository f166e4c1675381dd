"""The camera's health tally (daemon/matcher_health.py): the verdict from the daemon's running outcome counters."""

from __future__ import annotations

from taco_mav.daemon.matcher_health import MatcherHealth


def test_at_chance_after_enough_answers_that_said_nothing_and_usable_at_the_first_fix() -> None:
    h = MatcherHealth()
    assert h.count({"weak": 5}) is None and h.verdict == "unknown"  # five answers: too few to judge
    assert h.count({"weak": 5, "at_chance": 1}) == "at_chance"
    assert h.describe() == "mode AT_CHANCE: 0 of 6 fixed, 6 chance"
    assert h.count({"weak": 5, "at_chance": 1, "accepted": 1}) == "usable"


def test_answers_the_gnss_refutes_are_inconsistent_not_chance() -> None:
    """`refuted` answers disagree with the readings: they count as inconsistent, so a camera refuted on every answer
    is not called at chance (it placed something, wrongly), and the tally says so."""
    h = MatcherHealth()
    assert h.count({"refuted": 6}) == "usable"
    assert h.inconsistent == 1.0 and h.chance == 0.0 and h.accepted_share == 0.0
    h.count({"refuted": 6, "weak": 6})  # the window keeps the last 10: 4 refuted, 6 weak
    assert h.verdict == "usable" and h.chance == 0.6 and h.inconsistent == 0.4
