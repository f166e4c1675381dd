"""Whether the camera's answers are usable where the rover is: a running tally of the last answered triggers.

Each answered trigger ends in one outcome (core/frames.py `FixOutcome.reason`). Over the last WINDOW of them:
- accepted share: fixes made;
- chance share: answers that said nothing (`at_chance`: no better than the trigger's decoys or given by too few
  crops, core/answer_check.py; `weak`: under the mode's weight floor; `yaw_gate`: every crop's heading refused;
  `refuted`: from a camera the GNSS readings refute, gnss/guard.py);
- inconsistent share: answers that disagreed with the track (`innovation_gate`, `unconfirmed`).

The verdict is "unknown" until MIN_ANSWERS are in, "at_chance" while none of the window was accepted and at least
CHANCE_SHARE of it said nothing, "usable" otherwise (an accepted fix ends "at_chance" at once). Not in the paper;
the numbers: a live 3-D world at 3 m/s gives weak answers for 20-30 s at a stretch (docs/sitl.md), five triggers
at taco+'s 5 s, so a camera is called at chance only after ten answered triggers with no fix (about 50 s at the
rover profiles' trigger_time_s, or 25 s at their 2.5 s retry after a weak answer), most of them saying nothing.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping

__all__ = ["MatcherHealth"]

WINDOW = 10
MIN_ANSWERS = 6
CHANCE_SHARE = 0.7
CHANCE = frozenset({"at_chance", "weak", "yaw_gate", "refuted"})
INCONSISTENT = frozenset({"innovation_gate", "unconfirmed"})
ANSWERED = CHANCE | INCONSISTENT | {"accepted", "deferred", "stale", "nonfinite"}


class MatcherHealth:
    """The tally (module docstring). `count(fixes)` takes the daemon's running outcome counters and returns the
    new verdict when it changed, else None."""

    def __init__(self, window: int = WINDOW, min_answers: int = MIN_ANSWERS, chance_share: float = CHANCE_SHARE
                 ) -> None:
        self.min_answers, self.chance_share = min_answers, chance_share
        self.recent: deque[str] = deque(maxlen=window)
        self.verdict = "unknown"
        self._seen: dict[str, int] = {}

    def count(self, fixes: Mapping[str, int]) -> str | None:
        """fixes: outcome reason -> how many so far (monotone). The answers since the last call join the window
        (their order within one call is not known; accepted ones go last, so that a call with a fix ends usable)."""
        new: list[str] = []
        for reason in sorted(ANSWERED, key=lambda r: r == "accepted"):
            n = int(fixes.get(reason, 0))
            d = n - self._seen.get(reason, 0)
            self._seen[reason] = n
            new += [reason] * max(d, 0)
        self.recent.extend(new)
        return self._judge()

    def share(self, kinds: frozenset[str] | str) -> float:
        """Share of the window's outcomes in kinds (a set of reasons, or one), 0 when empty."""
        if not self.recent:
            return 0.0
        kinds = frozenset({kinds}) if isinstance(kinds, str) else kinds
        return sum(r in kinds for r in self.recent) / len(self.recent)

    @property
    def accepted_share(self) -> float:
        return self.share("accepted")

    @property
    def chance(self) -> float:
        return self.share(CHANCE)

    @property
    def inconsistent(self) -> float:
        return self.share(INCONSISTENT)

    def _judge(self) -> str | None:
        if len(self.recent) < self.min_answers and self.verdict == "unknown":
            verdict = "unknown"
        elif "accepted" not in self.recent and self.chance >= self.chance_share:
            verdict = "at_chance"
        else:
            verdict = "usable"
        if verdict == self.verdict:
            return None
        self.verdict = verdict
        return verdict

    def describe(self) -> str:
        """One line for a STATUSTEXT (at most 44 characters: with the daemon's prefix, a STATUSTEXT's 50)."""
        n = len(self.recent)
        return (f"mode AT_CHANCE: {round(self.accepted_share * n)} of {n} fixed, "
                f"{round(self.chance * n)} chance"[:44])
