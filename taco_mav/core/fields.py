"""Range metadata of a parameter field: what the profile loader checks (config/loading.py) and the one place
a parameter's bounds are written, beside its default and citation."""

from __future__ import annotations

from typing import Any

__all__ = ["bounded"]


def bounded(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False) -> dict[str, Any]:
    """Field metadata for a numeric range checked at load time: lo <= value <= hi (lo < value with open_lo);
    None leaves that side open."""
    return {"range": (lo, hi, open_lo)}
