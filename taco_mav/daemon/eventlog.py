"""JSONL event log of the daemon: one JSON object per line ({"t_wall": unix s, "event": name, ...}),
flushed at least every `flush_s` seconds and on close. numpy values are written as plain numbers/lists.
`read_events` reads the logs of every session under a --log-dir back."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from taco_mav.mavlink.appendlog import AppendLog


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


class EventLog(AppendLog):
    """Thread-safe JSONL writer; `path` None makes every call a no-op."""

    def __init__(self, path: str | Path | None, flush_s: float = 1.0) -> None:
        super().__init__(path, "t", flush_s)

    def write(self, event: str, **fields: Any) -> None:
        if not self.enabled:
            return
        line = json.dumps({"t_wall": round(time.time(), 6), "event": event, **_plain(fields)}, allow_nan=False)
        self.append(line + "\n")


def read_events(log_root: str | Path) -> list[dict[str, Any]]:
    """Every event of every session under a --log-dir (`log_root/<UTC start>/events.jsonl`, sessions in start
    order), as written; a line that is not a JSON object (cut short when a process was killed) is skipped."""
    out: list[dict[str, Any]] = []
    for path in sorted(Path(log_root).glob("*/events.jsonl")):
        for line in path.read_text().splitlines():
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(event, dict):
                out.append(event)
    return out
