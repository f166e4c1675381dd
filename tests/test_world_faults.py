"""Camera faults on cue for the simulated world camera (datasets/synthetic/world_faults.py), as the closed-loop
fault runs use them: `world:DIR?faults=FILE` freezes, blackens and stalls the rendered frames when FILE says so."""

from __future__ import annotations

import json
import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_camera import CAM, _world

from taco_mav.camera.sources import open_camera
from taco_mav.datasets.synthetic.world_camera import WorldSource
from taco_mav.errors import ConfigError


def _cue(path: Path, **data: object) -> None:
    path.write_text(json.dumps(data))
    t = time.time_ns() + 1_000_000  # a new modification time even within the file system's resolution
    os.utime(path, ns=(t, t))


def test_freeze_black_and_stall_on_cue(tmp_path: Path) -> None:
    _world(tmp_path)
    cue = tmp_path / "faults.json"
    src = open_camera(f"world:{tmp_path}?faults={cue}", CAM)
    assert isinstance(src, WorldSource) and src.faults is not None and src.faults.mode == "none"  # no file yet
    for k, yaw in enumerate((0.0, math.pi / 2, math.pi, 3 * math.pi / 2)):
        src.feed_pose(10.0 + k, 49.0, 8.4, yaw)
    t0, north = src.frame_near(10.0, 0.05)
    _, again = src.frame_near(10.0, 0.05)
    # healthy frames of one pose differ as a real sensor's do, so the daemon's frozen checks apply to this camera
    assert not src.noiseless and not np.array_equal(north, again) and np.abs(north.astype(int) - again).max() == 1
    _cue(cue, mode="freeze")
    t1, frozen = src.frame_near(11.0, 0.05)
    t2, still_frozen = src.frame_near(12.0, 0.05)
    assert (t1, t2) == (11.0, 12.0) and np.array_equal(frozen, still_frozen)  # new stamps, the same picture
    _cue(cue, mode="black")
    _, black = src.frame_near(12.0, 0.05)
    assert black.shape == north.shape and not black.any()
    _cue(cue, mode="none")
    _, south = src.frame_near(12.0, 0.05)
    assert not np.array_equal(south, frozen) and south.any()  # rendered again
    _cue(cue, mode="stall", seconds=0.3, id=1, thread="taco-matcher")
    start = time.monotonic()
    src.frame_near(13.0, 0.05)
    assert time.monotonic() - start < 0.3  # not the matcher's worker thread: no stall
    worker = threading.Thread(target=src.frame_near, args=(13.0, 0.05), name="taco-matcher")
    start = time.monotonic()
    worker.start()
    worker.join()
    assert time.monotonic() - start >= 0.3  # the worker's fetch blocked
    _cue(cue, mode="stall", seconds=0.3, id=2)
    start = time.monotonic()
    src.frame_near(13.0, 0.05)
    assert time.monotonic() - start >= 0.3  # the fetch blocked
    start = time.monotonic()
    src.frame_near(13.0, 0.05)
    assert time.monotonic() - start < 0.3  # once per id
    _cue(cue, mode="smoke")
    assert src.faults.mode == "none"  # an unknown fault is logged and ignored


def test_world_spec_with_an_unknown_option_is_refused(tmp_path: Path) -> None:
    _world(tmp_path)
    with pytest.raises(ConfigError, match=r"only faults=FILE is known"):
        open_camera(f"world:{tmp_path}?noise=2", CAM)
