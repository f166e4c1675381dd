"""Which SITL instance a closed-loop mission runs: one that no other mission on this machine holds.

A free instance is not enough: two missions started together (a campaign's workers) would both see instance I's
ports free and start two autopilots on them. Each mission therefore holds an exclusive `flock` on a lock file per
autopilot kind and instance (in the temporary folder) from the moment it picks the instance until its autopilot
has stopped; another mission skips a held instance. flock, not lockf: the lock belongs to the open file, so two
missions in one process (threads) exclude each other too, and the kernel drops it when a process dies, so a
killed worker frees its instance.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["lock_path", "reserved_instance"]


def lock_path(kind: str, instance: int) -> Path:
    """The lock file of `kind`'s (e.g. "ardurover", "px4") SITL instance `instance`."""
    return Path(tempfile.gettempdir()) / f"taco_mav-{kind}-instance-{instance}.lock"


@contextmanager
def reserved_instance(kind: str, candidates: Iterable[int], usable: Callable[[int], bool]) -> Iterator[int]:
    """The first of `candidates` that no other mission holds and that `usable` accepts (its ports free), held
    until the block ends. RuntimeError naming the kind when none is."""
    for inst in candidates:
        fd = os.open(lock_path(kind, inst), os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        if not usable(inst):
            os.close(fd)  # closing the only descriptor of the open file releases its flock
            continue
        try:
            yield inst
        finally:
            os.close(fd)
        return
    raise RuntimeError(f"no free {kind} SITL instance (every one held by another mission or its ports in use)")
