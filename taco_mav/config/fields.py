"""Building blocks shared by the profile sections: the estimator mode and the range metadata of a field (defined
in the core beside the estimator's own parameters, which use it too)."""

from __future__ import annotations

import enum

from taco_mav.core.fields import bounded

__all__ = ["Estimator", "bounded"]


class Estimator(enum.Enum):
    """Estimator mode: the paper exactly, or our improvements (taco+, docs/taco_plus.md)."""

    PAPER = "paper"
    TACO_PLUS = "taco+"
