"""The daemon's event log (daemon/eventlog.py): written as JSON lines with numpy values made plain, and read back
over every session of a --log-dir, a line cut short by a killed process skipped."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from taco_mav.daemon.eventlog import EventLog, read_events


def test_events_of_every_session_read_back_in_order(tmp_path: Path) -> None:
    for session, n in (("20261127T090000Z", 2), ("20261127T100000Z", 1)):
        log = EventLog(tmp_path / session / "events.jsonl")
        for k in range(n):
            log.write("fix", query_id=k, xy=np.array([1.5, -2.0]), session=session)
        log.close()
    with open(tmp_path / "20261127T100000Z" / "events.jsonl", "a") as f:
        f.write('{"t_wall": 1.0, "event": "st')  # killed mid-line
    events = read_events(tmp_path)
    assert [(e["session"], e["query_id"]) for e in events] == [
        ("20261127T090000Z", 0), ("20261127T090000Z", 1), ("20261127T100000Z", 0)]
    assert events[0]["xy"] == [1.5, -2.0] and events[0]["event"] == "fix"
    assert read_events(tmp_path / "none") == []
