"""Camera faults on cue for the simulated `world:` camera (simulation only): what a closed-loop mission
(`taco_mav.closedloop.faults`, `taco-mav mission --fault`) does to the rover's camera while the mission runs.

    --camera world:DIR?faults=FILE

FILE is a small JSON object the test rewrites whenever the fault changes; it is read again when its modification
time changes (one stat per frame):
    {"mode": "none"}                  frames as rendered
    {"mode": "freeze"}                the last frame before the freeze, again and again (a hung driver)
    {"mode": "black"}                 all-black frames (a covered or dead sensor)
    {"mode": "stall", "seconds": S, "id": K, "thread": NAME}
                                      the next frame fetch blocks for S wall seconds, once per id K, made by a
                                      thread whose name starts with NAME (default: any; "taco-matcher" is the
                                      daemon's matcher worker, which fetches the frame for its job: it stalls)
A missing file is "none"; an unreadable or unknown one is logged once and taken as "none".

A world camera with a fault file also behaves as a real sensor does when healthy: no two of its frames are bit
for bit the same (a few least significant bits flip, seeded), so the daemon's frozen-frame checks apply to it as to
a real camera (a rendered world is otherwise noiseless, and a rover at rest sees identical frames).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

MODES = ("none", "freeze", "black", "stall")
NOISE_PIXELS = 1024  # least significant bits flipped per healthy frame (a sensor's noise, for frozen checks)


class CameraFaults:
    """The fault FILE's current state, applied to each rendered frame (see the module docstring)."""

    def __init__(self, path: str | Path, seed: int = 0) -> None:
        self.path = Path(path)
        self._rng = np.random.default_rng(seed)
        self._mtime: float | None = None
        self._mode = "none"
        self._stall_s = 0.0
        self._stall_id: object = None
        self._stall_thread = ""
        self._stalled_ids: set[object] = set()
        self._frozen: tuple[float, np.ndarray] | None = None
        self._warned = False

    def _read(self) -> None:
        try:
            mtime = os.stat(self.path).st_mtime_ns
        except OSError:
            self._mode, self._mtime = "none", None
            return
        if mtime == self._mtime:
            return
        self._mtime = mtime
        try:
            data = json.loads(self.path.read_text())
            mode = data["mode"]
            if mode not in MODES:
                raise ValueError(f"mode {mode!r} (known: {', '.join(MODES)})")
            self._mode = mode
            self._stall_s = float(data.get("seconds", 0.0))
            self._stall_id = data.get("id")
            self._stall_thread = str(data.get("thread", ""))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            if not self._warned:
                log.warning("camera faults %s: %s; taken as no fault", self.path, exc)
                self._warned = True
            self._mode = "none"

    @property
    def mode(self) -> str:
        """The fault in force now: "none", "freeze", "black" or "stall"."""
        self._read()
        return self._mode

    def apply(self, t: float, frame: np.ndarray) -> tuple[float, np.ndarray]:
        """The frame the camera delivers for the rendered `frame` at autopilot time t (s)."""
        mode = self.mode
        frame = frame.copy()
        flat = frame.reshape(-1)
        flat[self._rng.integers(0, flat.size, NOISE_PIXELS)] ^= 1  # sensor noise: no two healthy frames alike
        if mode == "freeze":
            if self._frozen is None:
                self._frozen = (t, frame)
            return t, self._frozen[1]
        self._frozen = None
        if mode == "black":
            return t, np.zeros_like(frame)
        if (mode == "stall" and self._stall_id not in self._stalled_ids
                and threading.current_thread().name.startswith(self._stall_thread)):
            self._stalled_ids.add(self._stall_id)
            log.warning("camera faults: stalling this frame fetch for %.1f s", self._stall_s)
            time.sleep(max(self._stall_s, 0.0))
        return t, frame
