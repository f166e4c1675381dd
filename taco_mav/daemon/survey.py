"""Qualify an area before relying on it: on a drive with an honest GNSS receiver (a survey, `taco-mav run --shadow`
or its replay, `taco-mav eval --tlog --frames`), how the camera's answers compared with the receiver, for the whole
drive and stretch by stretch.

Each answered camera query is one `SurveyAnswer`: where along the drive (metres driven), whether the GNSS-free
estimator accepted it as a fix, and that fix's distance to the receiver at the frame's capture time (m; nan when
the answer gave no position or no receiver was there to compare). A stretch's verdict, by the stated rule:

- "usable": at least MIN_ANSWERS answers, at least MIN_ACCEPTED_SHARE of them accepted, and at least MIN_PRECISION
  of the accepted fixes within SUCCESS_M of the receiver (a fix that far from a receiver is wrong, whatever the
  receiver's own metre of error);
- "not usable": as many answers, and too few accepted or too many accepted fixes wrong;
- "too few answers": fewer than MIN_ANSWERS.

Why these numbers (not in the paper): the rover profiles ask the camera every 5 s (2.5 s after a weak answer); at
3 m/s, with a third of the answers accepted, a fix lands every 30-45 m, what the drift model needs to stay near a
metre (docs/taco_plus.md); a camera whose accepted fixes are wrong one time in twenty must not be relied on
(the precision target, 0.95). Pure bookkeeping; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["STRETCH_M", "SurveyAnswer", "SurveyVerdict", "stretches", "verdict"]

SUCCESS_M = 3.0
MIN_ANSWERS = 5
MIN_ACCEPTED_SHARE = 0.3
MIN_PRECISION = 0.95
STRETCH_M = 200.0  # the drive is judged in stretches this long (m driven)


@dataclass(frozen=True)
class SurveyAnswer:
    """t: capture time, s; odo_m: metres driven at capture; accepted: fused as a fix; error_m: the answer's position
    against the receiver, m (nan: none to compare)."""

    t: float
    odo_m: float
    accepted: bool
    error_m: float


@dataclass(frozen=True)
class SurveyVerdict:
    """A stretch (or the whole drive) from start_m to end_m driven: answers, accepted, accepted_compared (accepted
    fixes with a receiver to compare), precision (accepted within SUCCESS_M / accepted_compared; None without any),
    median_error_m of the compared accepted fixes (None without any), and the verdict."""

    start_m: float
    end_m: float
    answers: int
    accepted: int
    accepted_compared: int
    precision: float | None
    median_error_m: float | None
    verdict: str

    @property
    def accepted_share(self) -> float:
        return self.accepted / self.answers if self.answers else 0.0

    def as_dict(self) -> dict[str, float | int | str | None]:
        return {"start_m": round(self.start_m, 1), "end_m": round(self.end_m, 1), "answers": self.answers,
                "accepted": self.accepted, "accepted_share": round(self.accepted_share, 3),
                "precision": None if self.precision is None else round(self.precision, 3),
                "median_error_m": None if self.median_error_m is None else round(self.median_error_m, 3),
                "verdict": self.verdict}

    def line(self) -> str:
        """One line for a log or a terminal."""
        head = f"camera fixes {self.verdict.replace('usable', 'usable here')}"
        if not self.answers:
            return f"{head}: no camera answers"
        prec = "no fix compared" if self.precision is None else (
            f"{self.precision:.0%} within {SUCCESS_M:.0f} m of the receiver (median {self.median_error_m:.2f} m)")
        return f"{head}: {self.accepted} of {self.answers} answers accepted, {prec}"


def verdict(answers: list[SurveyAnswer], start_m: float = 0.0, end_m: float | None = None) -> SurveyVerdict:
    """The rule (module docstring) over `answers`."""
    n = len(answers)
    acc = [a for a in answers if a.accepted]
    errs = np.array([a.error_m for a in acc if math.isfinite(a.error_m)])
    precision = float(np.mean(errs <= SUCCESS_M)) if errs.size else None
    median = float(np.median(errs)) if errs.size else None
    if n < MIN_ANSWERS:
        word = "too few answers"
    elif len(acc) / n >= MIN_ACCEPTED_SHARE and precision is not None and precision >= MIN_PRECISION:
        word = "usable"
    else:
        word = "not usable"
    end = end_m if end_m is not None else max((a.odo_m for a in answers), default=start_m)
    return SurveyVerdict(start_m, end, n, len(acc), int(errs.size), precision, median, word)


def stretches(answers: list[SurveyAnswer], length_m: float = STRETCH_M) -> list[SurveyVerdict]:
    """The drive judged stretch by stretch: [0, length_m), [length_m, 2 length_m), ... metres driven, up to the
    last answer."""
    if not answers:
        return []
    last = max(a.odo_m for a in answers)
    out = []
    k = 0
    while k * length_m <= last:
        lo, hi = k * length_m, (k + 1) * length_m
        out.append(verdict([a for a in answers if lo <= a.odo_m < hi], lo, hi))
        k += 1
    return out
