"""Ground-station health (daemon/gcs.py): the taco_mode state machine and its values, and live over real UDP on
127.0.0.1 against the minimal autopilot: NAMED_VALUE_FLOAT taco_mode / taco_gnss / taco_hacc / taco_age /
taco_w once a second with the values the daemon's state has, and a STATUSTEXT for every change of mode."""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mav_autopilot import MiniAutopilot, free_udp_port, link_test_profile
from pymavlink.dialects.v20 import ardupilotmega as apm

from taco_mav.core.types import Estimate
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.daemon.gcs import GcsHealth, TacoMode
from taco_mav.mavlink import encoders

NAMES = {"taco_mode", "taco_gnss", "taco_hacc", "taco_age", "taco_w", "taco_cam", "taco_chnc"}


def _est(since_fix_s: float = 0.5, **extra) -> Estimate:
    return Estimate(10.0, np.zeros(2), 0.0, 1.0, np.eye(2), 0.5, since_fix_s, dict(extra))


def test_modes_values_and_changes() -> None:
    g = GcsHealth(camera_lost_s=3.0)
    fixes: Counter[str] = Counter()
    rep = g.update(0.0, None, None, True, "none", fixes, 0, 0, 0.0)
    assert rep.change is None and dict(rep.values) == {"taco_mode": 0.0, "taco_gnss": 0.0}
    rep = g.update(1.0, _est(0.7), 1.5, True, "ok", fixes, 1, 0, 0.8)
    assert rep.change == (6, "mode TRACKING (was STARTING)")
    assert dict(rep.values) == {"taco_mode": 1.0, "taco_gnss": 1.0, "taco_hacc": 1.5, "taco_age": 0.7, "taco_w": 0.8,
                                "taco_cam": 0.0, "taco_chnc": 0.0}
    # frames stop: faults counted, no frame reaches the matcher; camera lost once 3 s passed since the last one
    for t in (2.0, 3.0):
        fixes["no_frame"] += 1
        assert g.update(t, _est(), 2.0, True, "ok", fixes, 1, 0, 0.8).change is None
    fixes["stale_frame"] += 2
    rep = g.update(4.0, _est(), 3.0, True, "lost", fixes, 1, 0, 0.8)
    assert rep.change == (4, "mode CAMERA_LOST (was TRACKING)") and dict(rep.values)["taco_gnss"] == 2.0
    assert g.update(5.0, _est(), 3.0, True, "lost", fixes, 1, 0, 0.8).change is None  # no news: stays
    # a frame reaches the matcher, but every crop is off the map
    rep = g.update(6.0, _est(), 3.0, True, "rejected", fixes, 2, 1, 0.8)
    assert rep.change == (4, "mode OFF_MAP (was CAMERA_LOST)") and dict(rep.values)["taco_gnss"] == 3.0
    rep = g.update(7.0, _est(lock="lost"), 6.0, False, "ok", fixes, 3, 1, 0.4)  # back on the map; lock lost
    assert rep.change == (4, "mode RELOCALISING (was OFF_MAP)")
    assert g.update(8.0, _est(lock="confirming"), 4.0, True, "ok", fixes, 4, 1, 0.6).change == \
        (5, "mode CONFIRMING (was RELOCALISING)")
    assert g.update(9.0, _est(lock="locked"), 12.0, False, "ok", fixes, 5, 1, 0.6).change == \
        (4, "mode DEGRADED (was CONFIRMING)")
    rep = g.update(10.0, _est(math.inf, lock="locked"), math.nan, True, "ok", fixes, 6, 1, math.nan)
    assert rep.change == (6, "mode TRACKING (was DEGRADED)") and g.changes == 7
    v = dict(rep.values)
    assert (v["taco_hacc"], v["taco_age"], v["taco_w"]) == (1000.0, -1.0, 0.0)  # never NaN on the wire
    assert all(len(name) <= 10 for name in v)


def test_a_camera_at_chance_is_told_once_and_ends_at_the_next_fix() -> None:
    g = GcsHealth()
    fixes: Counter[str] = Counter(accepted=3)
    assert g.update(0.0, _est(), 1.0, True, "none", fixes, 3, 0, 0.9).change == (6, "mode TRACKING (was STARTING)")
    changes = []
    for t in range(1, 13):  # one answer a second: no fix, the answers no better than the trigger's decoys
        fixes["at_chance" if t % 4 else "weak"] += 1
        rep = g.update(float(t), _est(), 1.0 + t, True, "none", fixes, 3 + t, 0, 0.9)
        changes += [(t, rep.change)] if rep.change else []
        v = dict(rep.values)
    # the last of the three fixes leaves the window of ten at the tenth answer: called at chance then, once
    assert changes == [(10, (4, "mode AT_CHANCE: 0 of 10 fixed, 10 chance"))]
    assert v["taco_mode"] == TacoMode.AT_CHANCE and v["taco_cam"] == 0.0 and v["taco_chnc"] == 1.0
    # answers that disagree with the track are not chance: a window of them is not "at chance"
    fixes["accepted"] += 1
    rep = g.update(13.0, _est(), 1.0, True, "none", fixes, 16, 0, 0.9)
    assert rep.change == (6, "mode TRACKING (was AT_CHANCE)") and dict(rep.values)["taco_cam"] == 0.1
    for t in range(14, 24):
        fixes["innovation_gate"] += 1
        assert g.update(float(t), _est(), 1.0, True, "none", fixes, t + 3, 0, 0.9).change is None
    assert g.matcher.verdict == "usable" and g.matcher.inconsistent == 1.0


def test_named_value_float_encoding() -> None:
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=191)
    (msg,) = apm.MAVLink(None).parse_buffer(encoders.named_value_float(mav, 12_345, "taco_hacc", 2.5).pack(mav))
    assert (msg.name, msg.value, msg.time_boot_ms) == ("taco_hacc", 2.5, 12_345)
    (msg,) = apm.MAVLink(None).parse_buffer(encoders.named_value_float(mav, -5, "a_much_longer_name", math.nan)
                                            .pack(mav))
    assert (msg.name, msg.value, msg.time_boot_ms) == ("a_much_lon", -1.0, 0)


def test_live_names_at_1hz_with_the_daemons_values(tmp_path: Path) -> None:
    """6.5 s drive, IMU and attitude silent 3.0-4.5 s: every name about once a second (autopilot time stamps
    1 s apart, 0 at the first send when the autopilot's clock is not known yet); taco_mode 1 (TRACKING), 6 (DEGRADED) around the stall with a STATUSTEXT each way; taco_hacc the
    accuracy of the GPS_INPUT sent just before; taco_gnss 1 while GPS2 has a fix (first 1.5 s), then 2 (lost);
    taco_age below the 2 s trigger interval plus the matcher latency; taco_w 0 until the first answer, then the
    emulator's w in (0, 1]."""
    port = free_udp_port()
    daemon = Daemon(link_test_profile(),
                    DaemonOptions(connect=f"udpin:127.0.0.1:{port}", log_dir=tmp_path, matcher_latency_s=0.3))
    daemon.start()
    time.sleep(0.2)
    ap = MiniAutopilot(port, stall=(3.0, 4.5), gps_s=1.5)
    ap.start()
    time.sleep(6.5)
    daemon.stop()
    daemon.join(5.0)
    ap.stop()
    assert daemon.exit_code == 0
    nvf = ap.of_type("NAMED_VALUE_FLOAT")
    by_name: dict[str, list] = {}
    for r in nvf:
        by_name.setdefault(r.msg.name, []).append(r)
    assert set(by_name) == NAMES
    for name, rs in by_name.items():
        stamps = np.array([r.msg.time_boot_ms for r in rs if r.msg.time_boot_ms > 0]) * 1e-3  # 0: not mapped yet
        arrivals = np.array([r.t for r in rs])
        assert 5 <= len(rs) <= 8 and len(stamps) >= len(rs) - 1, (name, len(rs))
        assert np.allclose(np.diff(stamps), 1.0, atol=0.05), (name, np.diff(stamps))
        assert np.allclose(np.diff(arrivals), 1.0, atol=0.05), (name, np.diff(arrivals))
        assert stamps[-1] == pytest.approx(ap.ap_time(arrivals[-1] - ap.t_start), abs=0.05)  # autopilot ms
    el = lambda r: r.t - ap.t_start  # noqa: E731
    mode = [(el(r), r.msg.value) for r in by_name["taco_mode"]]
    assert mode[-1][1] == TacoMode.TRACKING and {v for _, v in mode} == {TacoMode.TRACKING, TacoMode.DEGRADED}
    assert all(v == TacoMode.DEGRADED for t, v in mode if 3.6 < t < 4.5)
    texts = [r.msg.text for r in ap.of_type("STATUSTEXT")]
    assert "TACO: mode TRACKING (was STARTING)" in texts and "TACO: mode DEGRADED (was TRACKING)" in texts
    assert "TACO: mode TRACKING (was DEGRADED)" in texts
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert [e["mode"] for e in events if e["event"] == "mode"] == ["TRACKING", "DEGRADED", "TRACKING"]
    gps = ap.of_type("GPS_INPUT")
    for r in by_name["taco_hacc"]:
        before = [g for g in gps if g.t <= r.t]
        assert before and r.msg.value == pytest.approx(before[-1].msg.horiz_accuracy, rel=1e-5)
    gnss = [(el(r), r.msg.value) for r in by_name["taco_gnss"]]
    assert all(v == 1.0 for t, v in gnss if t < 1.4) and all(v == 2.0 for t, v in gnss if t > 3.0)
    assert all(0.0 <= r.msg.value < 2.6 for r in by_name["taco_age"] if not 3.0 < el(r) < 5.0)
    w = [r.msg.value for r in by_name["taco_w"]]
    assert all(0.0 <= v <= 1.0 for v in w) and w[-1] > 0.0 and w[-1] == pytest.approx(daemon.fixes.last_weight)
    assert daemon.summary()["mode"] == "TRACKING"
