"""MAVLink telemetry log in pymavlink's tlog format: per message an 8-byte big-endian UNIX time in
microseconds followed by the raw packet; `mavutil.mavlink_connection(path)` reads it back."""

from __future__ import annotations

import struct
import time
from pathlib import Path

from taco_mav.mavlink.appendlog import AppendLog


class TlogWriter(AppendLog):
    """Append packets to `path`. Thread-safe; flushes at most every `flush_s` seconds and on close()."""

    def __init__(self, path: str | Path, flush_s: float = 1.0) -> None:
        super().__init__(path, "b", flush_s)

    def write(self, packet: bytes, unix_time_s: float | None = None) -> None:
        """One raw MAVLink packet, stamped with `unix_time_s` (default: now)."""
        stamp = int((time.time() if unix_time_s is None else unix_time_s) * 1e6)
        self.append(struct.pack(">Q", stamp) + bytes(packet))
