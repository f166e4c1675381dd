"""The camera's health tally (daemon/matcher_health.py): the verdict from the daemon's running outcome counters."""

from __future__ import annotations

from taco_mav.daemon.matcher_health import MatcherHealth


def test_at_chance_after_enough_answers_that_said_nothing_and_usable_at_the_first_fix() -> None:
    h = MatcherHealth()
    assert h.count({"weak": 5}) is None and h.verdict == "unknown"  # five answers: too few to judge
    assert h.count({"weak": 5, "at_chance": 1}) == "at_chance"
    assert h.describe() == "mode AT_CHANCE: 0 of 6 fixed, 6 chance"
    assert h.count({"weak": 5, "at_chance": 1, "accepted": 1}) == "usable"


def test_answers_the_gnss_refutes_count_as_chance() -> None:
    """`refuted` answers come from a camera that never agreed with the GNSS readings: as good as chance, so a
    camera refuted on every answer is called at chance (taco_mode 7), as one that says nothing is."""
    h = MatcherHealth()
    assert h.count({"refuted": 6}) == "at_chance"
    assert h.chance == 1.0 and h.inconsistent == 0.0 and h.accepted_share == 0.0
    assert h.count({"refuted": 6, "innovation_gate": 4}) == "usable"  # 6 of 10 chance: under 0.7
