"""A thread-safe append-only log file, flushed at most every `flush_s` seconds and on close (so a crash loses
at most that much); the tlog and the JSONL event log are both written through it. `session_dir` gives each
daemon session (`taco-mav run --log-dir ROOT`) its own folder, so no session appends to an older one's files."""

from __future__ import annotations

import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import IO

SESSION_FORMAT = "%Y%m%dT%H%M%SZ"  # UTC start time, sorts in time order


def session_dir(root: str | Path, now: datetime | None = None) -> Path:
    """Create and return a new folder ROOT/<UTC start time> (ROOT/<time>-2, -3, ... when started within the
    same second); ROOT is created if absent."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    stamp = (now or datetime.now(timezone.utc)).astimezone(timezone.utc).strftime(SESSION_FORMAT)
    for n in range(1, 1000):
        folder = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{root}: 999 sessions started at {stamp}")


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
