"""A thread-safe append-only log file, flushed at most every `flush_s` seconds and on close (so a crash loses
at most that much); the tlog and the JSONL event log are both written through it."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import IO


class AppendLog:
    """Append records to `path` ("b" mode for bytes, "t" for text); `path` None makes every call a no-op."""

    def __init__(self, path: str | Path | None, mode: str = "b", flush_s: float = 1.0) -> None:
        self.path = Path(path) if path is not None else None
        self._f: IO | None = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "ab") if mode == "b" else open(self.path, "a", encoding="utf-8")
        self._lock = threading.Lock()
        self._flush_s = flush_s
        self._last_flush = time.monotonic()
        self.count = 0

    @property
    def enabled(self) -> bool:
        return self._f is not None

    def append(self, record: bytes | str) -> None:
        """Write one record (already framed: a tlog packet with its stamp, or a line with its newline)."""
        with self._lock:
            if self._f is None:
                return
            self._f.write(record)
            self.count += 1
            now = time.monotonic()
            if now - self._last_flush >= self._flush_s:
                self._f.flush()
                self._last_flush = now

    def close(self) -> None:
        with self._lock:
            if self._f is not None:
                self._f.flush()
                self._f.close()
                self._f = None
