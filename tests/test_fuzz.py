"""The fuzz harness (tests/fuzz_harness.py) and its frames: a short seeded run against a real Daemon over UDP on
127.0.0.1 (the long one is tools/fuzz_mavlink.py), and the generator's determinism."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from fuzz_frames import MUTATIONS, STEP_S, AutopilotStream, Mutator  # noqa: E402
from fuzz_harness import FuzzOptions, run_fuzz  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

FRAMES = 5000


@pytest.fixture(scope="module")
def report() -> dict:
    return run_fuzz(FuzzOptions(frames=FRAMES, seed=0))


def test_no_crash_no_escaped_exception(report: dict) -> None:
    assert report["fuzz_frames"] == FRAMES
    assert sum(e["fuzz_frames"] for e in report["episodes"]) == FRAMES and len(report["episodes"]) == 3
    assert report["crashes"] == 0
    assert report["escaped_exceptions"] == 0
    assert all(not e["escaped_exceptions"] for e in report["episodes"])


def test_no_handler_errors(report: dict) -> None:
    assert report["handler_errors"] == 0
    assert not [k for k in report["logged_exceptions"] if k.startswith("taco_mav.daemon.daemon")]


def test_outputs_all_finite_and_in_range(report: dict) -> None:
    assert report["all_anchored"]
    for e in report["episodes"]:
        assert e["outputs"].get("GPS_INPUT", 0) >= 10, e["outputs"]
        assert e["outputs"]["GPS_INPUT"] == e["outputs"]["ODOMETRY"] == e["outputs"]["HIL_GPS"]
    assert report["nonfinite_output_fields"] == {}
    assert report["out_of_range_output_fields"] == {}


def test_every_frame_read_and_refusals_counted_by_reason(report: dict) -> None:
    assert report["datagrams_read"] == report["datagrams_sent"]  # none lost: the daemon looked at every one
    mut, rej = report["mutations"], report["rejected_inputs"]
    assert set(mut) == set(MUTATIONS) and sum(mut.values()) == FRAMES
    # one refusal per mutated frame at least (concatenations, splits and bit flips add more)
    assert rej["MAVLINK:unknown_id"] >= mut["unknown_id"]
    assert rej["MAVLINK:bad_crc"] >= mut["bad_crc"]
    assert rej["MAVLINK:truncated"] >= mut["truncate"] + mut["split"]
    assert report["rejected_by_reason"]["foreign_source"] >= mut["foreign_source"]
    assert rej["ATTITUDE:nonfinite"] > 0 and rej["HIGHRES_IMU:nonfinite"] > 0
    assert report["rejected_by_reason"]["no_time"] > 0
    # single corrupt timestamps (time_jump mutations) are dropped unconfirmed instead of re-anchoring
    jumps = sum(e["summary"]["dropped"].get("imu_time_jump_unconfirmed", 0) for e in report["episodes"])
    assert jumps > 0 and report["reboots"] <= jumps // 2


def test_stream_is_valid_mavlink() -> None:
    s = AutopilotStream("HIGHRES_IMU", boot_s=50.0)
    rx = mavlink.MAVLink(None)
    kinds = []
    for _ in range(101):
        for frame in s.step():
            (msg,) = rx.parse_buffer(frame)
            kinds.append(msg.get_type())
            assert (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 1)
    assert kinds.count("HIGHRES_IMU") == 101 and kinds.count("ATTITUDE") == 51 and kinds.count("HEARTBEAT") == 2
    assert kinds.count("GPS2_RAW") == 5 and kinds.count("SIMSTATE") == 11
    assert s.t == pytest.approx(50.0 + 101 * STEP_S)
    lat, lon = s.latlon(50.0 + 10.0)  # 50 m at 30 deg true
    assert (lat - 49.0) * 111_320.0 == pytest.approx(50.0 * 0.8660254, rel=1e-6)


def test_mutator_is_seeded() -> None:
    def draw(seed: int) -> list[tuple[str, list[bytes]]]:
        s = AutopilotStream("RAW_IMU")
        mut = Mutator(s, seed)
        out = []
        for _ in range(300):
            for frame in s.step():
                mut.recent.append(frame)
            out.append(mut.frame())
        return out

    a, b, c = draw(3), draw(3), draw(4)
    assert a == b and a != c
    assert {name for name, _ in a} == set(MUTATIONS)
    assert all(isinstance(d, bytes) for _, datagrams in a for d in datagrams)
    with pytest.raises(ValueError, match="bogus"):
        Mutator(AutopilotStream("RAW_IMU"), 0, ("bogus",))
