"""IMU and attitude source selection (daemon/imu_source.py): the first *valid* sample chooses, a source silent for
1 s gives way to one that delivers, the stream asked for is taken back once it streams, a pinned source is kept;
ATTITUDE_QUATERNION decodes like ATTITUDE. Live over real UDP on 127.0.0.1: corrupt IMU messages of other kinds
first, then a fallback RAW_IMU -> SCALED_IMU and ATTITUDE -> ATTITUDE_QUATERNION; and a seeded fuzz run in
"auto" mode with corrupt IMU messages first."""

from __future__ import annotations

import json
import math
import random
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from fuzz_frames import STEP_S, AutopilotStream, corrupt_imu
from fuzz_harness import FuzzOptions, run_fuzz
from mav_autopilot import free_udp_port, link_test_profile
from pymavlink.dialects.v20 import ardupilotmega as apm

from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.daemon.imu_source import InputSources, SourceSelector, attitude_quaternion
from taco_mav.mavlink.decoders import Decoders

MAV = apm.MAVLink(None, srcSystem=1, srcComponent=1)


def _wire(msg):
    """A message as the daemon sees it: packed and parsed back."""
    return apm.MAVLink(None).parse_buffer(msg.pack(MAV))[0]


# ----------------------------------------------------------------------------------------------- unit

def test_first_valid_sample_chooses_not_first_message() -> None:
    sel = SourceSelector(("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU"))
    assert not sel.offer("HIGHRES_IMU", False, 0.00)  # a NaN HIGHRES_IMU first: refused, chooses nothing
    assert sel.current is None and sel.take_switch() is None
    assert sel.offer("RAW_IMU", True, 0.01)
    sw = sel.take_switch()
    assert sel.current == "RAW_IMU" and sw is not None and (sw.old, sw.new, sw.silent_s) == (None, "RAW_IMU", 0.0)
    assert not sel.offer("HIGHRES_IMU", True, 0.02)  # a valid one of another kind now: not used
    assert sel.switches == 0 and sel.invalid == {"HIGHRES_IMU": 1}


def test_fallback_after_one_second_without_a_valid_sample() -> None:
    sel = SourceSelector(("RAW_IMU", "SCALED_IMU"), timeout_s=1.0)
    t = 0.0
    for _ in range(100):  # 1 s of both valid at 100 Hz: RAW_IMU (first) is used
        assert sel.offer("RAW_IMU", True, t) and not sel.offer("SCALED_IMU", True, t + 0.001)
        t += 0.01
    last_raw = t - 0.01
    sel.take_switch()
    used = []
    while t < last_raw + 1.5:  # RAW_IMU goes bad (all refused); SCALED_IMU keeps delivering
        sel.offer("RAW_IMU", False, t)
        used.append((t, sel.offer("SCALED_IMU", True, t + 0.001)))
        t += 0.01
    first = next(tt for tt, u in used if u)
    assert first - last_raw == pytest.approx(1.0, abs=0.011)
    assert all(u for tt, u in used if tt >= first)  # used from then on
    sw = sel.take_switch()
    assert (sw.old, sw.new) == ("RAW_IMU", "SCALED_IMU") and sw.silent_s > 1.0 and sel.switches == 1
    assert sel.offer("RAW_IMU", True, t) is False  # the old one back: the new one stays
    assert sel.silent_s(t) < 0.02


def test_the_stream_asked_for_is_returned_to_once_it_streams() -> None:
    """RAW_IMU (asked for) at its port's 0.5 Hz and SCALED_IMU2 at 2 Hz before the grant: the fallback to
    SCALED_IMU2, though SCALED_IMU2 never falls silent; a stray valid RAW_IMU, or four at 100 Hz, do not take it
    back; five stamped 10 ms apart (RAW_IMU granted) do, and it is kept from then on."""
    sel = SourceSelector(("RAW_IMU", "SCALED_IMU2"), timeout_s=1.0, preferred="RAW_IMU")
    assert sel.offer("RAW_IMU", True, 0.0, 100.0) and sel.current == "RAW_IMU"
    for k in range(1, 5):  # SCALED_IMU2 at 2 Hz; RAW_IMU's next sample is 2 s away
        sel.offer("SCALED_IMU2", True, 0.5 * k, 100.0 + 0.5 * k)
    assert sel.current == "SCALED_IMU2" and sel.switches == 1
    assert not sel.offer("RAW_IMU", True, 2.01, 101.7)  # one stray sample
    for k in range(4):  # four at 100 Hz, then a gap: not steady yet
        assert not sel.offer("RAW_IMU", True, 2.2, 102.2 + 0.01 * k)
    assert not sel.offer("RAW_IMU", True, 2.6, 102.6)
    assert not sel.offer("RAW_IMU", False, 2.61, 102.61)  # a refused sample breaks the run too
    used = [sel.offer("RAW_IMU", True, 3.0, 103.0 + 0.01 * k) for k in range(5)]
    assert used == [False, False, False, False, True] and sel.current == "RAW_IMU" and sel.switches == 2
    sw = sel.take_switch()
    assert sw is not None and (sw.old, sw.new) == ("SCALED_IMU2", "RAW_IMU")
    assert not sel.offer("SCALED_IMU2", True, 3.1, 103.1) and sel.offer("RAW_IMU", True, 3.1, 103.06)
    with pytest.raises(ValueError):
        SourceSelector(("RAW_IMU",), preferred="SCALED_IMU")


def test_pinned_source_is_never_left() -> None:
    sel = SourceSelector(("RAW_IMU", "HIGHRES_IMU"), pinned="HIGHRES_IMU")
    assert not sel.offer("RAW_IMU", True, 0.0) and sel.current == "HIGHRES_IMU"
    assert not sel.offer("RAW_IMU", True, 10.0) and sel.switches == 0
    assert sel.offer("HIGHRES_IMU", True, 10.01)
    with pytest.raises(ValueError):
        SourceSelector(("RAW_IMU",), pinned="SCALED_IMU")
    src = InputSources("HIGHRES_IMU")
    dec = Decoders()
    assert src.imu_reading(_wire(MAV.raw_imu_encode(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0)), dec, 0.0) is None
    assert dec.rejected == {}  # another kind than the pinned one is not even decoded


def test_second_imu_raw_imu_is_not_a_source() -> None:
    src, dec = InputSources(), Decoders()
    assert src.imu_reading(_wire(MAV.raw_imu_encode(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 1)), dec, 0.0) is None
    r = src.imu_reading(_wire(MAV.raw_imu_encode(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0)), dec, 0.0)
    assert r is not None and r.accel_frd[2] == pytest.approx(-9.80665) and src.imu.current == "RAW_IMU"


def _quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy)


@pytest.mark.parametrize("seed", range(3))
def test_attitude_quaternion_matches_attitude(seed: int) -> None:
    rng = np.random.default_rng(seed)
    dec = Decoders()
    for _ in range(20):
        roll, pitch, yaw = rng.uniform(-3.0, 3.0), rng.uniform(-1.4, 1.4), rng.uniform(-3.1, 3.1)
        p, q, r = rng.normal(0.0, 0.5, 3)
        a = dec.attitude(_wire(MAV.attitude_encode(1500, roll, pitch, yaw, p, q, r)))
        b = attitude_quaternion(_wire(MAV.attitude_quaternion_encode(1500, *_quat(roll, pitch, yaw), p, q, r)), dec)
        assert b is not None and b.t == pytest.approx(1.5)
        assert (b.roll, b.pitch, b.yaw) == pytest.approx((a.roll, a.pitch, a.yaw), abs=1e-5)
        assert b.euler_rates == pytest.approx(a.euler_rates, abs=1e-4)


def test_attitude_quaternion_refusals_counted() -> None:
    dec = Decoders()
    assert attitude_quaternion(_wire(MAV.attitude_quaternion_encode(1, math.nan, 0, 0, 0, 0, 0, 0)), dec) is None
    assert attitude_quaternion(_wire(MAV.attitude_quaternion_encode(1, 0.0, 0, 0, 0, 0, 0, 0)), dec) is None
    a = attitude_quaternion(_wire(MAV.attitude_quaternion_encode(1, 1.0, 0, 0, 0, math.inf, 0, 0)), dec)
    assert a is not None and a.euler_rates == (0.0, 0.0, 0.0)
    assert dec.rejected == {"ATTITUDE_QUATERNION:nonfinite": 1, "ATTITUDE_QUATERNION:range": 1,
                            "ATTITUDE_QUATERNION:rates": 1}


def test_corrupt_imu_frames_never_decode_as_samples() -> None:
    stream, rng, dec = AutopilotStream("RAW_IMU"), random.Random(0), Decoders()
    rx = apm.MAVLink(None)
    kinds = set()
    for _ in range(300):
        (msg,) = rx.parse_buffer(corrupt_imu(stream, rng))
        kinds.add(msg.get_type())
        assert dec.imu(msg) is None
    assert kinds == {"HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"}
    reasons = {k.split(":")[1] for k in dec.rejected}
    assert reasons == {"nonfinite", "accel_range", "no_time", "all_zero"}


# ----------------------------------------------------------------------------------------------- live

class _Sender:
    """An autopilot as raw frames over UDP to the daemon's udpin: `step(replace)` sends one 10 ms step of the
    stream, each message kind in `replace` swapped for what its function returns (None: left out)."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.dest = ("127.0.0.1", port)
        self.stream = AutopilotStream("RAW_IMU")
        self.rx = apm.MAVLink(None)
        self.got: list[tuple[float, object]] = []
        self.t0 = time.monotonic()

    def send(self, frame: bytes) -> None:
        self.sock.sendto(frame, self.dest)

    def step(self, replace: dict | None = None) -> None:
        replace = replace or {}
        for frame in self.stream.step():
            kind = self.rx.parse_buffer(frame)[0].get_type()
            if kind in replace:
                msg = replace[kind]()
                if msg is not None:
                    self.send(self.stream.pack(msg))
            else:
                self.send(frame)
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                break
            for msg in self.rx.parse_buffer(data) or []:
                self.got.append((time.monotonic(), msg))
        ahead = self.t0 + (self.stream.k * STEP_S) - time.monotonic()  # real time: the daemon's clock
        if ahead > 0:
            time.sleep(ahead)

    def of_type(self, kind: str) -> list[tuple[float, object]]:
        return [(t, m) for t, m in self.got if m.get_type() == kind]


def test_live_corrupt_first_then_fallbacks(tmp_path: Path) -> None:
    """HEARTBEAT, then 50 corrupt IMU messages of every kind (a NaN HIGHRES_IMU first), then a valid RAW_IMU
    stream: RAW_IMU is chosen and GPS_INPUT flows. At 3 s RAW_IMU turns out of range while a valid SCALED_IMU
    runs beside it, and ATTITUDE turns NaN while ATTITUDE_QUATERNION is sent: both fall back after 1 s, counted,
    logged as events and STATUSTEXT, and the output keeps its rate and fix."""
    port = free_udp_port()
    daemon = Daemon(link_test_profile(), DaemonOptions(connect=f"udpin:127.0.0.1:{port}", log_dir=tmp_path))
    daemon.start()
    time.sleep(0.2)
    ap = _Sender(port)
    s, tx = ap.stream, ap.stream.tx
    try:
        ap.send(s.pack(s.message("HEARTBEAT")))
        time.sleep(0.05)
        ap.send(s.pack(tx.highres_imu_encode(int(s.t * 1e6), math.nan, 0.0, -9.8, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0,
                                             0x3F)))
        rng = random.Random(1)
        for _ in range(50):
            ap.send(corrupt_imu(s, rng))
        for _ in range(300):  # 3 s valid
            ap.step()
        bad_raw = lambda: tx.raw_imu_encode(int(s.t * 1e6), 0, 0, 32767, 0, 0, 0, 0, 0, 0)  # noqa: E731
        scaled = lambda: tx.scaled_imu_encode(int(s.t * 1e3), 0, 0, -1000, 0, 0, 0, 0, 0, 0)  # noqa: E731
        nan_att = lambda: tx.attitude_encode(int(s.t * 1e3), math.nan, 0.0, s.yaw, 0.0, 0.0, 0.0)  # noqa: E731
        for _ in range(400):  # 4 s: the fallbacks
            ap.step({"RAW_IMU": bad_raw, "ATTITUDE": nan_att})
            ap.send(s.pack(scaled()))
            if s.k % 2 == 0:
                ap.send(s.pack(tx.attitude_quaternion_encode(int(s.t * 1e3), *_quat(0.0, 0.0, s.yaw), 0, 0, 0)))
        time.sleep(0.2)
    finally:
        daemon.stop()
        daemon.join(5.0)
        ap.sock.close()
    summ = daemon.summary()
    assert daemon.exit_code == 0 and summ["dropped"].get("handler_error", 0) == 0
    assert summ["sources"]["imu"]["source"] == "SCALED_IMU" and summ["sources"]["imu"]["switches"] == 1
    assert summ["sources"]["attitude"]["source"] == "ATTITUDE_QUATERNION"
    assert summ["sources"]["attitude"]["switches"] == 1
    assert summ["rejected_inputs"]["HIGHRES_IMU:nonfinite"] >= 1 and summ["rejected_inputs"]["RAW_IMU:accel_range"] > 300
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    chosen = [(e["input"], e["old"], e["new"]) for e in events if e["event"] == "input_source"]
    assert chosen == [("attitude", None, "ATTITUDE"), ("imu", None, "RAW_IMU"), ("imu", "RAW_IMU", "SCALED_IMU"),
                      ("attitude", "ATTITUDE", "ATTITUDE_QUATERNION")] or \
        sorted(chosen[2:]) == [("attitude", "ATTITUDE", "ATTITUDE_QUATERNION"), ("imu", "RAW_IMU", "SCALED_IMU")]
    switch_s = [e["silent_s"] for e in events if e["event"] == "input_source" and e["old"]]
    assert all(1.0 < x < 1.1 for x in switch_s), switch_s
    texts = [m.text for _, m in ap.of_type("STATUSTEXT")]
    assert any("imu RAW_IMU silent 1.0s: using SCALED_IMU" in t for t in texts), texts
    gps = ap.of_type("GPS_INPUT")
    el = np.array([t - ap.t0 for t, _ in gps])
    fix = np.array([m.fix_type for _, m in gps])
    assert len(el) >= 25 and el[0] < 1.0  # RAW_IMU was taken at once despite the corrupt messages before it
    late = el > 5.0  # after the fallbacks: still 5 Hz, 3D fix, on the truth
    assert late.sum() >= 9 and np.all(fix[late] == 3) and np.all(np.diff(el) < 0.3)
    t_last, last = gps[-1]
    lat, lon = s.latlon(s.boot_s + (t_last - ap.t0))
    dn = (last.lat * 1e-7 - lat) * 111_320.0
    de = (last.lon * 1e-7 - lon) * 111_320.0 * math.cos(math.radians(lat))
    assert math.hypot(dn, de) < 3.0


def test_fuzz_auto_source_with_corrupt_imu_first() -> None:
    """3 000 mutated frames (the tool's done-check runs 30 000), the daemon choosing its IMU source itself
    after 200 corrupt IMU messages of every kind: it picks each episode's valid stream and keeps sending valid
    GPS_INPUT (all finite and in range), mostly a 3D fix (time-jump mutations may degrade it for a while)."""
    report = run_fuzz(FuzzOptions(frames=3000, seed=1, imu_message="auto", corrupt_imu_first=200))
    assert report["crashes"] == 0 and report["escaped_exceptions"] == 0 and report["handler_errors"] == 0
    assert report["all_anchored"]
    assert report["imu_sources"] == {"RAW_IMU": "RAW_IMU", "HIGHRES_IMU": "HIGHRES_IMU", "SCALED_IMU": "SCALED_IMU"}
    assert report["nonfinite_output_fields"] == {} and report["out_of_range_output_fields"] == {}
    for e in report["episodes"]:
        assert e["gps_input_during_fuzz"] >= 15  # ~1 s of wall time at 20 Hz (10 autopilot s at 10x)
        assert e["gps_input_fix3_during_fuzz"] >= 0.5 * e["gps_input_during_fuzz"], e["fix_types"]
        assert e["summary"]["sources"]["imu"]["switches"] == 0
