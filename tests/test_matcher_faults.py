"""Matcher faults: exceptions, malformed answers and hangs are logged and counted, the loop goes on, a hung
matcher is timed out (query cancelled, worker replaced) and never blocks the loop or shutdown. The fix
pipeline runs with its real worker thread and a real Localiser; the last test drives the whole daemon over
loopback UDP."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import pytest
from fault_helpers import run_pipeline, small_camera_profile, straight_drive
from mav_autopilot import MiniAutopilot, free_udp_port

from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.daemon.daemon import Daemon, DaemonOptions

BAD = MatchResult(np.eye(2), np.array([np.nan, 0.0]), 0.9)


def _raise_on(calls: set[int]):
    def fault(call: int) -> object:
        if call in calls:
            raise RuntimeError(f"CUDA out of memory (planted, call {call})")
        return None
    return fault


def test_exceptions_are_counted_and_the_loop_goes_on(caplog: pytest.LogCaptureFixture) -> None:
    run = run_pipeline(small_camera_profile(), straight_drive(16.0), _raise_on({1, 2}))
    f = run.stats.fixes
    assert f["matcher_error"] == 2 and f["accepted"] == run.stats.queries - 2 >= 4, f
    assert sum("matcher failed on query" in r.message for r in caplog.records) == 2  # logged with traceback
    assert any(t == "no fix: matcher_error" for t in run.texts)
    assert run.sigma[run.t > run.t[-1] - 4.0].min() < 5.0  # fixes after the failures keep it small


@pytest.mark.parametrize("answer, reason", [([], "matcher_error"), ([None] * 5, "matcher_error"),
                                            (["garbage"] * 5, "matcher_error"), ([BAD] * 5, "nonfinite")])
def test_malformed_answers(answer: list, reason: str) -> None:
    run = run_pipeline(small_camera_profile(), straight_drive(10.0), lambda call: answer if call == 0 else None)
    assert run.stats.fixes[reason] == 1 and run.stats.fixes["accepted"] == run.stats.queries - 1, run.stats.fixes


def test_hang_times_out_and_a_fresh_worker_takes_over() -> None:
    """Call 1 hangs (until released): after matcher_timeout_s its query is cancelled and counted, the worker is
    abandoned and a new one answers the next queries; the stuck thread's late answer is dropped."""
    release = threading.Event()
    run = run_pipeline(small_camera_profile(), straight_drive(16.0),
                       lambda call: release.wait(30.0) and None if call == 1 else None,
                       wait_s=0.6, matcher_timeout_s=0.3)
    f = run.stats.fixes
    assert f["matcher_timeout"] == 1 and f["accepted"] >= 4, f
    assert run.pipe.stuck == 1 and run.stop_s < 1.5
    assert any(t.startswith("matcher timeout") for t in run.texts)
    release.set()
    deadline = time.monotonic() + 5.0
    while run.pipe.stuck and time.monotonic() < deadline:
        time.sleep(0.01)
    assert run.pipe.stuck == 0 and run.pipe._results.empty()  # the late answer was dropped
    assert run.sigma[run.t > run.t[-1] - 4.0].min() < 5.0


def test_matcher_that_always_hangs_is_bounded() -> None:
    """Every call hangs: two workers are abandoned (MAX_STUCK), then queries are cancelled as matcher_hung;
    the 1-sigma grows honestly and stopping takes about a second, not forever."""
    run = run_pipeline(small_camera_profile(), straight_drive(10.0), lambda call: time.sleep(20.0),
                       wait_s=0.4, matcher_timeout_s=0.2)
    f = run.stats.fixes
    assert f["matcher_timeout"] == 2 and f["matcher_hung"] >= 1 and f.get("accepted", 0) == 0, f
    assert run.pipe.stuck == 2 and run.stop_s < 1.5
    assert run.sigma[-1] > 10.0 and np.all(run.errors <= 3.0 * run.sigma + 0.01)


class HangingMatcher:
    """Never answers (until released): a GPU driver deadlock, say."""

    name = "hang"
    needs_true_pose = True  # never looks at a frame: runs without a camera

    def __init__(self) -> None:
        self.release = threading.Event()

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        self.release.wait(60.0)
        return []


def test_daemon_keeps_its_rate_and_stops_with_a_hung_matcher(tmp_path: Path) -> None:
    port = free_udp_port()
    matcher = HangingMatcher()
    daemon = Daemon(small_camera_profile(), DaemonOptions(connect=f"udpin:127.0.0.1:{port}", log_dir=tmp_path,
                                                          matcher_timeout_s=1.0), matcher=matcher)
    daemon.start()
    time.sleep(0.2)
    ap = MiniAutopilot(port)
    ap.start()
    time.sleep(7.0)
    t0 = time.monotonic()
    daemon.stop()
    daemon.join(5.0)
    stop_s = time.monotonic() - t0
    ap.stop()
    matcher.release.set()
    assert daemon.exit_code == 0 and stop_s < 2.0
    s = daemon.summary()
    assert s["fixes"].get("matcher_timeout", 0) >= 1 and s["fixes"].get("accepted", 0) == 0, s
    times = np.array([r.t for r in ap.of_type("GPS_INPUT")])
    gaps = np.diff(times)
    assert len(times) >= 28 and gaps.mean() < 0.215 and gaps.max() < 0.3  # 5 Hz kept throughout
    assert "matcher_timeout" in (tmp_path / "events.jsonl").read_text()


class WeakMatcher:
    """Always answers, never confidently (w = 0.05): a matcher looking at the wrong place."""

    name = "weak"
    needs_true_pose = True  # never looks at a frame: runs without a camera

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        return [MatchResult(np.eye(2), np.array([3.0, -2.0]), 0.05) for _ in crops]


def test_taco_plus_lock_loss_is_logged_and_announced(tmp_path: Path) -> None:
    """taco+ in the daemon: weak answers only -> lock declared lost, written to the event log as a "lock" event,
    sent to the autopilot as a STATUSTEXT, and the grid search starts (queries with more than five crops)."""
    port = free_udp_port()
    profile = small_camera_profile(estimator="taco+", plus={"trigger_sigma_m": 0.3, "lost_after_s": 2.0})
    daemon = Daemon(profile, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", log_dir=tmp_path), matcher=WeakMatcher())
    daemon.start()
    time.sleep(0.2)
    ap = MiniAutopilot(port)
    ap.start()
    time.sleep(8.0)
    daemon.stop()
    daemon.join(5.0)
    ap.stop()
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    locks = [e for e in events if e.get("event") == "lock"]
    assert locks and locks[0]["kind"] == "lock_lost"
    texts = [r.msg.text for r in ap.of_type("STATUSTEXT")]
    assert any("lock lost" in t for t in texts), texts
    crops = [len(e["crop_centres"]) for e in events if e.get("event") == "fix" and "crop_centres" in e]
    assert max(crops) > 5 and daemon.summary()["fixes"].get("weak", 0) >= 4
    state = daemon.summary()["estimator"]  # the taco+ internals are in every stats line
    assert state["mode"] == "taco+" and state["lock"] in ("lost", "confirming", "locked")
    assert state["fix_scale"] == 1.0 and {"speed_error", "accel_bias", "compass_bias"} <= set(state)
