"""The one progress-bar helper: library loops take `enabled` and stay silent when it is False."""

from __future__ import annotations

from typing import Iterable, Iterator, TypeVar

from tqdm import tqdm

T = TypeVar("T")


def progress_bar(items: Iterable[T], total: int | None = None, desc: str = "", enabled: bool = True) -> Iterator[T]:
    """Wrap an iterable in a tqdm bar on stderr when enabled; otherwise return it unchanged."""
    if not enabled:
        return iter(items)
    return iter(tqdm(items, total=total, desc=desc, unit="sample", leave=False, mininterval=0.5))
