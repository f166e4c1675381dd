"""Building blocks shared by the profile sections: the estimator mode and the range metadata of a field."""

from __future__ import annotations

import enum
from typing import Any

__all__ = ["Estimator", "bounded"]


class Estimator(enum.Enum):
    """Estimator mode: the paper exactly, or our improvements (issue 7)."""

    PAPER = "paper"
    TACO_PLUS = "taco+"


def bounded(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False) -> dict[str, Any]:
    """Field metadata for a numeric range checked at load time: lo <= value <= hi (lo < value with open_lo);
    None leaves that side open."""
    return {"range": (lo, hi, open_lo)}
