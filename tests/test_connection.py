"""Connection strings, the tlog format (read back by pymavlink), and a Link round trip over UDP on 127.0.0.1."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from mav_autopilot import free_udp_port  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from taco_mav.errors import ConfigError  # noqa: E402
from taco_mav.mavlink.connection import Link, parse_connection  # noqa: E402
from taco_mav.mavlink.requests import ekf3_gate_warnings  # noqa: E402


def test_parse_connection() -> None:
    assert parse_connection("udpin:0.0.0.0:14550", 57600) == ("udpin:0.0.0.0:14550", 57600)
    assert parse_connection("tcp:127.0.0.1:5760", 57600) == ("tcp:127.0.0.1:5760", 57600)
    assert parse_connection("/dev/ttyAMA0:921600", 57600) == ("/dev/ttyAMA0", 921600)
    assert parse_connection("/dev/ttyACM0,115200", 57600) == ("/dev/ttyACM0", 115200)
    assert parse_connection("/dev/ttyUSB0", 57600) == ("/dev/ttyUSB0", 57600)
    with pytest.raises(ConfigError):
        parse_connection("udpin:14550", 57600)
    with pytest.raises(ConfigError):
        parse_connection(" ", 57600)


def test_link_udp_roundtrip_and_tlog(tmp_path: Path) -> None:
    port = free_udp_port()
    link = Link(f"udpin:127.0.0.1:{port}", sysid=0, compid=191, tlog=tmp_path / "t.tlog", wall_clock=lambda: 1.7e9)
    peer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=7, source_component=1,
                                      dialect="ardupilotmega")
    try:
        peer.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GROUND_ROVER, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                0, 0, 4)
        got = []
        deadline = time.monotonic() + 3
        while not got and time.monotonic() < deadline:
            got = link.recv(0.1)
        assert got[0].get_type() == "HEARTBEAT"
        assert link.adopt_autopilot(got[0]) and link.target_system == 7 and link.mav.srcSystem == 7
        link.heartbeat()
        back = peer.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
        assert back.get_srcSystem() == 7 and back.get_srcComponent() == 191
        assert back.type == mavutil.mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    finally:
        link.close()
        peer.close()
    log = mavutil.mavlink_connection(str(tmp_path / "t.tlog"), dialect="ardupilotmega")
    a, b = log.recv_msg(), log.recv_msg()
    assert (a.get_srcSystem(), b.get_srcSystem()) == (7, 7)
    assert a._timestamp == pytest.approx(1.7e9) and b.get_srcComponent() == 191
    assert log.recv_msg() is None


def test_ekf3_gate_warnings() -> None:
    assert ekf3_gate_warnings(10, 2.0, 0.5) == []
    w = ekf3_gate_warnings(5, 1.0, 3.0)
    assert len(w) == 3 and "satellites_visible=5" in w[0]


def test_udp_datagrams_parsed_alone_and_refusals_counted() -> None:
    """A truncated frame does not swallow the next datagram's frame; every refused frame is counted by reason."""
    port = free_udp_port()
    link = Link(f"udpin:127.0.0.1:{port}", sysid=0, compid=191)
    tx = mavutil.mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = bytes(tx.raw_imu_encode(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0).pack(tx))
    bad_crc = frame[:-1] + bytes([frame[-1] ^ 0x55])
    unknown = bytes([0xFD, 3, 0, 0, 0, 1, 1, 0x39, 0x30, 0x00, 1, 2, 3, 0, 0])  # msgid 12345
    sent = [frame[:12], frame, bad_crc, unknown, b"\x01\x02\x03", frame + frame]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            for d in sent:
                s.sendto(d, ("127.0.0.1", port))
            got: list = []
            deadline = time.monotonic() + 3
            while link.datagrams < len(sent) and time.monotonic() < deadline:
                got += link.recv(0.05)
            got += link.recv(0.05)
        finally:
            link.close()
    assert [g.get_type() for g in got] == ["RAW_IMU"] * 3 and link.received == 3 and link.datagrams == len(sent)
    assert dict(link.rejected) == {"MAVLINK:truncated": 1, "MAVLINK:bad_crc": 1, "MAVLINK:unknown_id": 1,
                                   "MAVLINK:bad_prefix": 1}
