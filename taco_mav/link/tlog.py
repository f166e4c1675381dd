"""MAVLink telemetry log in pymavlink's tlog format: per message an 8-byte big-endian UNIX time in
microseconds followed by the raw packet; `mavutil.mavlink_connection(path)` reads it back."""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path
from typing import BinaryIO


class TlogWriter:
    """Append packets to `path`. Thread-safe; flushes at most every `flush_s` seconds and on close()."""

    def __init__(self, path: str | Path, flush_s: float = 1.0) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f: BinaryIO | None = open(self.path, "ab")
        self._lock = threading.Lock()
        self._flush_s = flush_s
        self._last_flush = time.monotonic()
        self.count = 0

    def write(self, packet: bytes, unix_time_s: float | None = None) -> None:
        """One raw MAVLink packet, stamped with `unix_time_s` (default: now)."""
        stamp = int((time.time() if unix_time_s is None else unix_time_s) * 1e6)
        with self._lock:
            if self._f is None:
                return
            self._f.write(struct.pack(">Q", stamp) + bytes(packet))
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
