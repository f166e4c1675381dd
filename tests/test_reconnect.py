"""Bounded TCP connects and non-blocking reconnects (mavlink/reconnect.py) against real sockets on loopback,
including a peer that drops SYNs (a listening socket whose backlog is full)."""

import logging
import socket
import time

import pytest

from pymavlink import mavutil

from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.reconnect import TimedTcp, pace_tcp_reconnect


def _blackhole() -> tuple[socket.socket, list[socket.socket], int]:
    """A listener that never accepts, its one-slot backlog filled: further SYNs are dropped."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(0)
    port = srv.getsockname()[1]
    filler = socket.create_connection(("127.0.0.1", port), timeout=1.0)
    return srv, [filler], port


def test_start_up_connect_to_a_silent_peer_is_bounded():
    srv, held, port = _blackhole()
    try:
        TimedTcp.connect_timeout_s = 0.3
        t0 = time.monotonic()
        with pytest.raises(OSError):
            TimedTcp(f"127.0.0.1:{port}", autoreconnect=True, retries=2, reconnect_delay=0.1)
        assert time.monotonic() - t0 < 1.5  # 2 x 0.3 s + 0.1 s, not 2 x the kernel's SYN timeout
    finally:
        TimedTcp.connect_timeout_s = 2.0
        for s in (srv, *held):
            s.close()


def test_refused_port_waits_and_connects_once_the_autopilot_listens(caplog: pytest.LogCaptureFixture):
    """`--connect tcp:` before the autopilot listens: the link opens waiting (one warning), the loop's receive
    never blocks, and once a peer listens on the port the link connects within the pacing (1 s) and carries
    MAVLink both ways."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there: connect is refused at once
    with caplog.at_level(logging.INFO, logger="taco_mav.mavlink.reconnect"):
        t0 = time.monotonic()
        link = Link(f"tcp:127.0.0.1:{port}", 1, 191)
        assert time.monotonic() - t0 < 0.5 and link.conn.waiting and link.conn.port is None
        for _ in range(30):  # 1.5 s of loop turns with nothing listening
            t = time.monotonic()
            assert link.recv(0.05) == []
            link.heartbeat()  # dropped while unconnected, never raises
            assert time.monotonic() - t < 0.2
        srv = socket.socket()
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind(("127.0.0.1", port))
        srv.listen(1)
        srv.settimeout(3.0)
        t_listen = time.monotonic()
        while link.conn.port is None and time.monotonic() - t_listen < 3.0:
            link.recv(0.05)
        peer, _ = srv.accept()
        connected_after = time.monotonic() - t_listen
        link.heartbeat()
        peer.settimeout(2.0)
        data = peer.recv(1024)
        ap = mavutil.mavlink.MAVLink(None)
        ap.robust_parsing = True
        msgs = ap.parse_buffer(data) or []
        peer.sendall(mavutil.mavlink.MAVLink(None, srcSystem=1, srcComponent=1).heartbeat_encode(
            mavutil.mavlink.MAV_TYPE_GROUND_ROVER, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0).pack(
            mavutil.mavlink.MAVLink(None, srcSystem=1, srcComponent=1)))
        got = []
        t1 = time.monotonic()
        while not got and time.monotonic() - t1 < 2.0:
            got = link.recv(0.05)
        link.close()
        peer.close()
        srv.close()
    assert connected_after < 1.5
    assert [m.get_type() for m in msgs] == ["HEARTBEAT"] and msgs[0].get_srcComponent() == 191
    assert [m.get_type() for m in got] == ["HEARTBEAT"]
    waits = [r for r in caplog.records if "no autopilot listening" in r.getMessage()]
    assert len(waits) == 1 and f"tcp:127.0.0.1:{port}" in waits[0].getMessage()
    assert any("connected" in r.getMessage() and "reconnected" not in r.getMessage() for r in caplog.records)


def test_reconnect_never_blocks_and_resumes_when_the_peer_listens_again():
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    link = Link(f"tcp:127.0.0.1:{port}", 1, 191)
    peer, _ = srv.accept()
    conn = link.conn
    assert isinstance(conn, TimedTcp)
    now = [0.0]
    assert pace_tcp_reconnect(conn, interval_s=1.0, clock=lambda: now[0], connect_timeout_s=0.5)
    srv.close()
    peer.close()  # the autopilot went away: EOF, then nothing listens
    worst = 0.0
    for _ in range(20):  # 2 s of loop turns on the fake clock while the port is closed
        t = time.monotonic()
        assert conn.recv() == b""
        worst = max(worst, time.monotonic() - t)
        now[0] += 0.1
    assert conn.port is None and worst < 0.05
    # a silent peer (SYNs dropped): attempts are started, polled, abandoned, but never block the loop
    hole = socket.socket()
    hole.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    hole.bind(("127.0.0.1", port))
    hole.listen(0)
    filler = socket.create_connection(("127.0.0.1", port), timeout=1.0)
    for _ in range(30):
        t = time.monotonic()
        assert conn.recv() == b""
        worst = max(worst, time.monotonic() - t)
        now[0] += 0.1
    assert conn.port is None and worst < 0.05
    filler.close()
    hole.close()
    # the autopilot listens again: the next paced attempt connects, and select() watches the new socket
    back = socket.socket()
    back.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    back.bind(("127.0.0.1", port))
    back.listen(1)
    for _ in range(30):
        conn.recv()
        now[0] += 0.1
        time.sleep(0.01)
        if conn.port is not None:
            break
    assert conn.port is not None and conn.fd == conn.port.fileno()
    server_side, _ = back.accept()
    server_side.sendall(b"\xfd")  # one byte of a MAVLink 2 frame reaches the new socket
    time.sleep(0.05)
    assert conn.recv(1) == b"\xfd"
    for s in (server_side, back):
        s.close()
    link.close()
