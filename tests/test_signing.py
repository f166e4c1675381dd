"""MAVLink 2 signing: the key file, the signature-first guard, and the daemon over real UDP on 127.0.0.1 with a
signed autopilot (tests/mav_autopilot.py) plus peers that send unsigned, wrongly signed and foreign traffic."""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path
from typing import Callable

import pytest

os.environ.setdefault("MAVLINK20", "1")
from mav_autopilot import MiniAutopilot, free_udp_port, link_test_profile  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from taco_mav.daemon.daemon import Daemon, DaemonOptions  # noqa: E402
from taco_mav.errors import ConfigError  # noqa: E402
from taco_mav.mavlink import signing  # noqa: E402
from taco_mav.mavlink.connection import Link  # noqa: E402

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
m = mavutil.mavlink
N_BAD = 20  # frames each bad peer sends


def _peer(port: int, sysid: int = 1, compid: int = 1, key: bytes | None = None) -> mavutil.mavfile:
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=sysid, source_component=compid,
                                      dialect="ardupilotmega")
    conn.mav.robust_parsing = True  # refused frames come back as BAD_DATA instead of raising
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True)
    return conn


def _until(pred: Callable[[], bool], timeout_s: float = 5.0, poll: Callable[[], None] | None = None) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if poll is not None:
            poll()
        if pred():
            return True
        time.sleep(0.01)
    return pred()


# ---------------------------------------------------------------------------- key file
def test_key_file_raw_and_hex(tmp_path: Path) -> None:
    raw = tmp_path / "raw.key"
    raw.write_bytes(KEY)
    hexed = tmp_path / "hex.key"
    hexed.write_text(KEY.hex().upper() + "\n")
    assert signing.load_key(raw) == KEY and signing.load_key(hexed) == KEY
    assert signing.key_file(str(hexed)) == hexed


@pytest.mark.parametrize("content, needle", [
    (b"abc", "got 3 bytes"), (KEY + b"\n", "got 33 bytes"), ("ab" * 31, "got 62 bytes"),
    (bytes(32), "all-zero key"), ("00" * 32, "all-zero key")])
def test_key_file_errors_name_the_file(tmp_path: Path, content: bytes | str, needle: str) -> None:
    path = tmp_path / "bad.key"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(ConfigError) as err:
        signing.load_key(path)
    text = str(err.value)
    assert str(path) in text and needle in text and "\n" not in text


def test_key_file_missing_or_directory(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="nope.key: file not found"):
        signing.load_key(tmp_path / "nope.key")
    with pytest.raises(ConfigError, match="is a directory"):
        signing.load_key(tmp_path)


# ---------------------------------------------------------------------------- Link level
def _recv_all(link: Link, want: int, timeout_s: float = 3.0) -> list:
    got: list = []
    _until(lambda: len(got) >= want, timeout_s, poll=lambda: got.extend(link.recv(0.02)))
    return got


def test_forged_future_timestamp_cannot_lock_out_the_autopilot() -> None:
    """A wrongly signed frame carrying the autopilot's stream (link id, sysid, compid) and a far-future signing
    timestamp is refused as bad_signature and does not make the autopilot's next genuine frames look replayed
    (pymavlink alone records the timestamp before checking the signature)."""
    port = free_udp_port()
    link = Link(f"udpin:127.0.0.1:{port}", sysid=0, compid=191, signing_key=KEY)
    ap = _peer(port, key=KEY)
    ap.mav.signing.link_id = 7
    attacker = _peer(port, key=OTHER_KEY)
    attacker.mav.signing.link_id = 7
    attacker.mav.signing.timestamp = ap.mav.signing.timestamp + 10**12
    try:
        ap.mav.heartbeat_send(m.MAV_TYPE_GROUND_ROVER, m.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
        assert [g.get_type() for g in _recv_all(link, 1)] == ["HEARTBEAT"]
        attacker.mav.raw_imu_send(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
        _until(lambda: link.rejected["RAW_IMU:bad_signature"] == 1, poll=lambda: link.recv(0.02))
        for k in range(5):
            ap.mav.raw_imu_send(2_000_000 + k, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
        got = _recv_all(link, 5)
        assert [g.get_type() for g in got] == ["RAW_IMU"] * 5 and all(g.get_signed() for g in got)
        assert dict(link.rejected) == {"RAW_IMU:bad_signature": 1}
        # a genuine frame sent again (a replay) is refused as such
        link.conn.port.sendto(got[-1].get_msgbuf(), ("127.0.0.1", port))
        _until(lambda: link.rejected["RAW_IMU:replay"] == 1, poll=lambda: link.recv(0.02))
        assert link.rejected["RAW_IMU:replay"] == 1
    finally:
        for c in (ap, attacker):
            c.close()
        link.close()


# ---------------------------------------------------------------------------- the daemon
@pytest.fixture(scope="module")
def signed_run(tmp_path_factory: pytest.TempPathFactory):
    """The daemon with --signing-key, a signed autopilot for 3 s, and bad peers sending N_BAD RAW_IMU each:
    unsigned (sysid 1/1), wrongly signed (1/1), correctly signed but foreign (sysid 2)."""
    key_path = tmp_path_factory.mktemp("key") / "signing.key"
    key_path.write_text(KEY.hex())
    port = free_udp_port()
    daemon = Daemon(link_test_profile(), DaemonOptions(connect=f"udpin:127.0.0.1:{port}", signing_key=key_path))
    daemon.start()
    time.sleep(0.2)
    ap = MiniAutopilot(port)
    ap.conn.setup_signing(KEY, sign_outgoing=True)
    ap.start()
    wrong_rx = _peer(port, sysid=250, compid=1, key=OTHER_KEY)  # a receiver with another key
    plain_rx = _peer(port, sysid=251, compid=1)  # a receiver without signing
    unsigned, wrong, foreign = _peer(port), _peer(port, key=OTHER_KEY), _peer(port, sysid=2, key=KEY)
    time.sleep(1.0)
    for conn in (wrong_rx, plain_rx):  # make the daemon's udpin send to them too
        conn.mav.heartbeat_send(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, 4)
    for k in range(N_BAD):
        for conn in (unsigned, wrong, foreign):
            conn.mav.raw_imu_send(int((ap.boot_s + 1.0) * 1e6) + k, 0, 0, -20000, 0, 0, 0, 0, 0, 0)
    wrong_got: list = []
    plain_got: list = []

    def poll() -> None:
        for conn, store in ((wrong_rx, wrong_got), (plain_rx, plain_got)):
            while (msg := conn.recv_msg()) is not None:
                store.append(msg)

    _until(lambda: False, 2.0, poll=poll)
    daemon.stop()
    daemon.join(5.0)
    ap.stop()
    wrong_badsig = wrong_rx.mav.signing.badsig_count
    for conn in (wrong_rx, plain_rx, unsigned, wrong, foreign):
        conn.close()
    yield daemon, ap, wrong_got, plain_got, wrong_badsig


def test_signed_autopilot_is_followed(signed_run) -> None:
    daemon, ap, _, _, _ = signed_run
    assert daemon.exit_code == 0
    gps = ap.of_type("GPS_INPUT")
    assert len(gps) >= 10 and gps[-1].msg.fix_type == 3
    assert daemon.summary()["imu_samples"] > 100


def test_outgoing_is_signed_with_our_key(signed_run) -> None:
    daemon, ap, _, plain_got, _ = signed_run
    # the autopilot's pymavlink checks every signature with KEY: what it accepted was signed with it
    assert all(r.msg.get_signed() for r in ap.received) and len(ap.of_type("GPS_INPUT")) >= 10
    assert ap.conn.mav.signing.badsig_count == 0 and ap.conn.mav.signing.goodsig_count >= len(ap.received)
    # a receiver without a key sees the signed flag and the 13-byte signature block on every frame
    assert plain_got and all(struct.unpack("B", bytes(msg.get_msgbuf()[2:3]))[0] & 1 for msg in plain_got)
    assert any(msg.get_type() == "GPS_INPUT" for msg in plain_got)


def test_receiver_with_another_key_rejects_us(signed_run) -> None:
    _, _, wrong_got, plain_got, wrong_badsig = signed_run
    assert len(plain_got) >= 5
    assert [msg for msg in wrong_got if msg.get_type() != "BAD_DATA"] == []
    assert wrong_badsig >= len(plain_got) - 2  # every frame it was sent (give or take the last in flight)


def test_unsigned_wrong_and_foreign_input_ignored_and_counted(signed_run) -> None:
    daemon, _, _, _, _ = signed_run
    rejected = daemon.summary()["rejected_inputs"]
    assert rejected.get("RAW_IMU:unsigned") == N_BAD
    assert rejected.get("RAW_IMU:bad_signature") == N_BAD
    assert rejected.get("RAW_IMU:foreign_source") == N_BAD
    assert rejected.get("HEARTBEAT:bad_signature") == 1  # the other-key receiver's hello
    # the -20 g samples never reached the decoders (they would have been counted as accel_range)
    assert not any(k.endswith("accel_range") for k in rejected)
    assert daemon.stats.reboots == 0
