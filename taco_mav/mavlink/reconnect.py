"""Bounded connects and non-blocking reconnects for a pymavlink TCP client (`tcp:HOST:PORT`).

pymavlink's `mavtcp` connects with a blocking `socket.connect`: to a host that drops SYNs (down, firewalled,
wrong address on a routed network) each attempt blocks for the kernel's SYN timeout (about 2 min on Linux),
six attempts at start-up. It also reconnects inside `recv`/`write`: up to 6 attempts with a 1 s sleep between
them, then it raises, and tries again at the next call; in the daemon loop that blocks everything (outputs,
health, shutdown), and after a reconnect the connection's `fd` (which the loop's select() waits on) still names
the old socket.

- `TimedTcp` is `mavtcp` with each start-up attempt bounded by `connect_timeout_s`.
- `pace_tcp_reconnect` changes one connection so that a reconnect never blocks: a non-blocking connect is
  started at most once per `interval_s`, polled at each later `recv`/`write`, and given up after
  `connect_timeout_s`; meanwhile `recv` returns no data and `write` drops the packet (as a cut radio would).

Serial (`mavserial`, pyserial): a USB adapter that is unplugged makes every read raise (EIO, or "readiness to
read but no data") and every write fail; pymavlink then prints, retries inside `write` only, and leaves the
dead descriptor for select(). `pace_serial_reconnect` closes the port at the first error (one warning, no
traceback), drops writes and reads nothing while it is gone, and tries to reopen the same path at the same
baud at most once per `interval_s`; a device that comes back (the same /dev name, or a udev symlink such as
/dev/serial/by-id/...) is used again, and the daemon's link watch reports the outage as for UDP or TCP.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import select
import socket
import time
from typing import Any, Callable

from pymavlink import mavutil

log = logging.getLogger(__name__)


CONNECT_TIMEOUT_S = 2.0  # per TCP connect attempt, s; a LAN or loopback peer answers within milliseconds


def _ready(sock: socket.socket) -> socket.socket:
    """A connected TCP socket set up as pymavlink's mavtcp sets its own: non-blocking, Nagle off."""
    sock.setblocking(False)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


class TimedTcp(mavutil.mavtcp):
    """pymavlink's TCP client whose start-up connect attempts each give up after `connect_timeout_s`.

    wait: when no attempt connects (nothing listens yet: an autopilot still booting, a SITL started after us),
    open anyway, unconnected (`waiting` True, `port` None, `fd` -1) instead of raising, so that the paced
    reconnect (`pace_tcp_reconnect`) connects in the loop once the peer listens."""

    connect_timeout_s = CONNECT_TIMEOUT_S

    def __init__(self, device: str, *args: Any, wait: bool = False, **kwargs: Any) -> None:
        self.wait, self.waiting = wait, False
        super().__init__(device, *args, **kwargs)
        if self.waiting:
            self.port.close()
            self.port, self.fd = None, -1

    def do_connect(self) -> None:
        attempts = max(int(self.retries), 1)
        for k in range(attempts):
            try:
                sock = socket.create_connection(self.destination_addr, timeout=self.connect_timeout_s)
                break
            except OSError as exc:
                self.port = None
                if k < attempts - 1:
                    time.sleep(self.reconnect_delay)
                    continue
                if not self.wait:
                    raise
                log.warning("no autopilot listening at tcp:%s:%d yet (%s): trying again every second until one "
                            "does", *self.destination_addr, exc.strerror or exc)
                self.waiting = True
                self.port = socket.socket(socket.AF_INET, socket.SOCK_STREAM)  # mavfile needs a descriptor
                return
        self.port = _ready(sock)


def open_tcp(device: str, source_system: int, source_component: int, dialect: str) -> TimedTcp:
    """A `TimedTcp` for "tcp:HOST:PORT" with autoreconnect, as mavutil.mavlink_connection would build a mavtcp,
    but trying once at start-up: a peer not listening yet leaves it waiting, connected later without blocking
    (`pace_tcp_reconnect`, applied here), so a stop request is never held up by connect attempts."""
    mavutil.set_dialect(dialect)
    conn = TimedTcp(device[4:], autoreconnect=True, retries=1, source_system=source_system,
                    source_component=source_component, wait=True)
    pace_tcp_reconnect(conn)
    return conn


def pace_tcp_reconnect(conn: Any, interval_s: float = 1.0, clock: Callable[[], float] = time.monotonic,
                       connect_timeout_s: float = CONNECT_TIMEOUT_S) -> bool:
    """Make `conn` (a pymavlink connection) reconnect without blocking: a non-blocking connect at most once per
    `interval_s` seconds of `clock`, abandoned after `connect_timeout_s`. Returns False (and changes nothing)
    unless it is a TCP client with autoreconnect."""
    if not isinstance(conn, mavutil.mavtcp) or not conn.autoreconnect:
        return False
    last_try = [-math.inf]
    pending: list[Any] = [None, 0.0]  # the socket being connected, when it started

    def start(now: float) -> socket.socket:
        if conn.port is not None:
            conn.port.close()
            conn.port = None
        if now - last_try[0] < interval_s:
            raise ConnectionRefusedError("reconnect paced: next attempt later")
        last_try[0] = now
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setblocking(False)
        err = sock.connect_ex(conn.destination_addr)
        if err not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EALREADY):
            sock.close()
            raise ConnectionRefusedError(err, os.strerror(err))
        pending[:] = [sock, now]
        return sock

    def reconnect() -> None:
        now = clock()
        sock = pending[0] if pending[0] is not None else start(now)
        _, writable, _ = select.select([], [sock], [], 0)
        if not writable:
            if now - pending[1] >= connect_timeout_s:
                sock.close()
                pending[0] = None
                raise TimeoutError(f"TCP connect to {conn.destination_addr[0]}:{conn.destination_addr[1]} timed out")
            raise BlockingIOError(errno.EINPROGRESS, "TCP connect in progress")
        pending[0] = None
        err = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if err:
            sock.close()
            raise ConnectionRefusedError(err, os.strerror(err))
        conn.port, conn.fd = _ready(sock), sock.fileno()  # select() must watch the new socket
        first = getattr(conn, "waiting", False)
        conn.waiting = False
        log.info("TCP link %s:%d %s", *conn.destination_addr, "connected" if first else "reconnected")

    receive = conn.__dict__.setdefault("unpaced_recv", conn.recv)  # pacing again replaces, never stacks

    def recv(n: int | None = None) -> bytes:
        try:
            if conn.port is None:
                reconnect()
            return receive(n)  # on EOF or reset pymavlink calls reconnect() itself
        except OSError as exc:
            if conn.port is not None:
                raise
            log.debug("TCP reconnect: %s", exc)
            return b""

    conn.reconnect, conn.recv = reconnect, recv
    return True


def _open_serial(device: str, baud: int) -> Any:
    """A pyserial port as pymavlink's mavserial opens one (non-blocking reads, no flow control): opened at
    1200 baud, then set to `baud` (works around kernels that otherwise keep the old rate)."""
    import serial

    port = serial.Serial(device, 1200, timeout=0, dsrdtr=False, rtscts=False, xonxoff=False)
    port.baudrate = baud
    return port


def pace_serial_reconnect(conn: Any, interval_s: float = 1.0, clock: Callable[[], float] = time.monotonic) -> bool:
    """Make `conn` (a pymavlink serial connection) survive its device vanishing: on the first read or write
    error the port is closed and `conn.fd` set to None; while it is gone `recv` returns b"" and `write` drops
    the packet; every `interval_s` seconds of `clock` the device path is opened again at `conn.baud`. Returns
    False (and changes nothing) for any other connection."""
    if not isinstance(conn, mavutil.mavserial):
        return False
    import serial

    errors = (OSError, serial.SerialException, ValueError, TypeError)  # pyserial raises TypeError on a closed fd
    state = {"since": math.nan, "last_try": -math.inf}
    baud = int(conn.baud)

    def lost(exc: BaseException) -> None:
        if conn.portdead:
            return
        log.warning("serial %s lost (%s): reopening it every %.0f s", conn.device, exc, interval_s)
        conn.portdead, conn.fd = True, None  # select() must not watch a dead (or reused) descriptor
        state["since"] = clock()
        try:
            conn.port.close()
        except errors:
            pass
        mav = conn.mav  # a frame cut short by the unplug is never joined to the first bytes after it
        mav.buf, mav.buf_index, mav.expected_length = bytearray(), 0, mavutil.mavlink.HEADER_LEN_V1 + 2

    def reopen() -> bool:
        now = clock()
        if now - state["last_try"] < interval_s:
            return False
        state["last_try"] = now
        try:
            port = _open_serial(conn.device, baud)
        except errors as exc:
            log.debug("serial %s: not back yet (%s)", conn.device, exc)
            return False
        conn.port, conn.fd, conn.portdead = port, port.fileno(), False
        if conn.rtscts:
            conn.set_rtscts(True)
        log.warning("serial %s reopened at %d baud after %.1f s", conn.device, baud, now - state["since"])
        return True

    receive = conn.__dict__.setdefault("unpaced_recv", conn.recv)  # pacing again replaces, never stacks

    def recv(n: int | None = None) -> bytes:
        if conn.portdead and not reopen():
            return b""
        try:
            return receive(n)
        except errors as exc:
            lost(exc)
            return b""

    def write(buf: bytes) -> int:
        if conn.portdead:
            return -1  # dropped, as a cut radio would
        try:
            return conn.port.write(bytes(buf))
        except errors as exc:
            lost(exc)
            return -1

    conn.recv, conn.write, conn.reset = recv, write, reopen
    return True
