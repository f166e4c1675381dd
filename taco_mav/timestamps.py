"""KITTI-format timestamp files: one `YYYY-MM-DD HH:MM:SS.fffffffff` per line (oxts/, image_02/, frames/).

A leaf module (numpy and the error types only): the dataset readers (`datasets/kitti_io.py`, which re-exports it)
and the daemon's image-folder camera (`camera/sources.py` FolderSource) share it, so the camera, and with it
`daemon/`, needs nothing from `datasets/` to read a folder of frames.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["read_timestamps"]


def read_timestamps(path: Path) -> np.ndarray:
    """KITTI `YYYY-MM-DD HH:MM:SS.fffffffff` lines -> (N,) int64 nanoseconds since the unix epoch.

    KITTI does not state a time zone; the strings are read as UTC. Trailing blank lines are allowed, blank
    lines in between are not. Times must not go backwards (repeats are allowed and logged).
    """
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataError(f"{path}: timestamps file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read ({exc})") from None
    lines = text.rstrip().splitlines()
    if not lines or not lines[0].strip():
        raise DataError(f"{path}: no timestamps")
    stripped = [line.strip() for line in lines]
    try:
        ns = np.array(stripped, dtype="datetime64[ns]").astype(np.int64)
        bad = np.flatnonzero(ns == np.iinfo(np.int64).min)  # NaT
    except ValueError:
        bad = np.array([i for i, s in enumerate(stripped) if not _parses_as_time(s)])
        ns = np.zeros(0, dtype=np.int64)
    if len(bad):
        i = int(bad[0])
        raise DataError(f"{path}, line {i + 1}: not a KITTI timestamp (YYYY-MM-DD HH:MM:SS.fffffffff): {stripped[i]!r}")
    steps = np.diff(ns)
    back = np.flatnonzero(steps < 0)
    if len(back):
        i = int(back[0]) + 1
        raise DataError(f"{path}, line {i + 1}: time goes backwards ({stripped[i - 1]} -> {stripped[i]})")
    if np.any(steps == 0):
        log.warning("%s: %d repeated timestamps", path, int(np.sum(steps == 0)))
    return ns


def _parses_as_time(s: str) -> bool:
    if len(s) < 19 or s[4] != "-" or s[7] != "-":
        return False
    try:
        return not np.isnat(np.datetime64(s, "ns"))
    except ValueError:
        return False
