"""The one progress-bar helper: library loops take `enabled` and stay silent when it is False.

Log records must not tear the bars apart: the CLI installs `TqdmHandler`, which writes each record through
`tqdm.write` (above any bar in progress, which is then redrawn below it). Library code only logs through
`logging.getLogger(__name__)`; it never adds handlers.
"""

from __future__ import annotations

import logging
import sys
from typing import Iterable, Iterator, TypeVar

from tqdm import tqdm

T = TypeVar("T")

__all__ = ["TqdmHandler", "progress_bar"]


def progress_bar(items: Iterable[T], total: int | None = None, desc: str = "", enabled: bool = True) -> Iterator[T]:
    """Wrap an iterable in a tqdm bar on stderr when enabled; otherwise return it unchanged."""
    if not enabled:
        return iter(items)
    return iter(tqdm(items, total=total, desc=desc, unit="sample", leave=False, mininterval=0.5))


class TqdmHandler(logging.Handler):
    """A logging handler that prints through `tqdm.write` on stderr, so records and progress bars interleave
    cleanly (a record is printed above the bars, which are redrawn after it)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never raise into the caller
            self.handleError(record)
