"""Bench: loading KITTI odometry sequence 05 (raw drive 2011_09_30_drive_0018, 2761 OXTS packets).

`kitti_load_seq05_s` is the best of three wall-clock loads, seconds (parse, convert, project to UTM). The key
is absent when no KITTI root is found (`$TACO_KITTI_ROOT` or ../shared/data/kitti_raw beside the checkout).
"""

from __future__ import annotations

import logging
import time

from taco_mav.datasets.kitti import default_kitti_root, load_sequence
from taco_mav.errors import DataError

log = logging.getLogger(__name__)


def run(progress: bool = False) -> dict[str, float]:
    """{"kitti_load_seq05_s": seconds} or {} without the data."""
    root = default_kitti_root()
    if root is None:
        log.info("kitti_load: no KITTI raw root, section skipped")
        return {}
    times = []
    for _ in range(3):
        start = time.perf_counter()
        try:
            load_sequence(root, "05")
        except DataError as exc:
            log.info("kitti_load: %s, section skipped", exc)
            return {}
        times.append(time.perf_counter() - start)
    return {"kitti_load_seq05_s": min(times)}
