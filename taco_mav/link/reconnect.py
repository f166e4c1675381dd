"""Non-blocking reconnects for a pymavlink TCP client (`tcp:HOST:PORT` with autoreconnect).

pymavlink's `mavtcp` reconnects inside `recv`/`write`: up to 6 connect attempts with a 1 s sleep between
them, then it raises, and tries again at the next call. In the daemon loop that blocks everything (outputs,
health, shutdown) for about 6 s at a time while the autopilot is away, and after a successful reconnect the
connection's `fd` (which the loop's select() waits on) still names the old socket. `pace_tcp_reconnect`
changes one connection object so that a reconnect is a single connect attempt, at most one per `interval_s`;
between attempts `recv` returns no data and `write` drops the packet (as a cut radio would).

A connect to a host that is down without refusing (no RST) still blocks for the kernel's SYN timeout: use it
on loopback or a LAN, or a serial/UDP link otherwise.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any, Callable

from pymavlink import mavutil

log = logging.getLogger(__name__)


def pace_tcp_reconnect(conn: Any, interval_s: float = 1.0, clock: Callable[[], float] = time.monotonic) -> bool:
    """Make `conn` (a pymavlink connection) reconnect without blocking, one attempt per `interval_s` seconds
    of `clock`. Returns False (and changes nothing) unless it is a TCP client with autoreconnect."""
    if not isinstance(conn, mavutil.mavtcp) or not conn.autoreconnect:
        return False
    conn.retries, conn.reconnect_delay = 1, 0.0  # do_connect: one attempt, no sleep, raise when refused
    connect, receive = conn.reconnect, conn.recv
    last_try = [-math.inf]

    def reconnect() -> None:
        now = clock()
        if now - last_try[0] < interval_s:
            if conn.port is not None:
                conn.port.close()
                conn.port = None
            raise ConnectionRefusedError("reconnect paced: next attempt later")
        last_try[0] = now
        connect()
        conn.fd = conn.port.fileno()  # select() must watch the new socket
        log.info("TCP link %s:%d reconnected", *conn.destination_addr)

    def recv(n: int | None = None) -> bytes:
        if conn.port is None:
            try:
                reconnect()
            except OSError as exc:
                log.debug("TCP reconnect: %s", exc)
                return b""
        return receive(n)

    conn.reconnect, conn.recv = reconnect, recv
    return True
