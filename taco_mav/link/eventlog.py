"""JSONL event log of the daemon: one JSON object per line ({"t_wall": unix s, "event": name, ...}),
flushed at least every `flush_s` seconds and on close. numpy values are written as plain numbers/lists."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


class EventLog:
    """Thread-safe JSONL writer; `path` None makes every call a no-op."""

    def __init__(self, path: str | Path | None, flush_s: float = 1.0) -> None:
        self._f: TextIO | None = None
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._f = open(path, "a", encoding="utf-8")
        self._lock = threading.Lock()
        self._flush_s = flush_s
        self._last = time.monotonic()
        self.count = 0

    def write(self, event: str, **fields: Any) -> None:
        if self._f is None:
            return
        line = json.dumps({"t_wall": round(time.time(), 6), "event": event, **_plain(fields)}, allow_nan=False)
        with self._lock:
            if self._f is None:
                return
            self._f.write(line + "\n")
            self.count += 1
            now = time.monotonic()
            if now - self._last >= self._flush_s:
                self._f.flush()
                self._last = now

    def close(self) -> None:
        with self._lock:
            if self._f is not None:
                self._f.flush()
                self._f.close()
                self._f = None
