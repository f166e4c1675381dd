"""The MAVLink connection: open a pymavlink link from a connection string, send and receive whole messages,
log every packet both ways to a tlog, keep our identity (sysid/compid) and the autopilot's, sign (MAVLink 2
signing, `signing.py`) and count every refused frame by reason.

UDP: every datagram is parsed on its own (MAVLink never splits a frame across datagrams), so a truncated or
garbled datagram cannot swallow the start of the next one. Refused frames go to `rejected` as
"MAVLINK:<reason>" (bad_prefix, bad_crc, bad_length, bad_flags, bad_payload, truncated, unknown_id) or, for
signing, "<MESSAGE>:<reason>" (unsigned, bad_signature, replay).

Connection strings are pymavlink's: "udpin:0.0.0.0:14550", "udpout:192.168.1.10:14550", "tcp:127.0.0.1:5760",
or a serial device, optionally with its baud rate: "/dev/ttyAMA0:921600" (or "/dev/ttyAMA0,921600"; without
one the profile's link.baud). A serial device that vanishes (USB unplugged) is reopened at the same path and
baud once it is back (`reconnect.pace_serial_reconnect`).
"""

from __future__ import annotations

import logging
import os
import re
import select
import socket
import time
from collections import Counter
from pathlib import Path
from typing import Any, Callable

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from taco_mav.errors import ConfigError, TacoError  # noqa: E402
from taco_mav.mavlink import signing  # noqa: E402
from taco_mav.mavlink.reconnect import open_tcp, pace_serial_reconnect  # noqa: E402
from taco_mav.mavlink.tlog import TlogWriter  # noqa: E402

log = logging.getLogger(__name__)

_NETWORK = ("udpin:", "udpout:", "udp:", "udpbcast:", "tcp:", "tcpin:")
AUTOPILOT_TYPES_EXCLUDED = (mavutil.mavlink.MAV_AUTOPILOT_INVALID,)
# pymavlink's BAD_DATA reasons (MAVError texts) -> our reason keys
_MAX_SKIP = 500
TCP_LINGER_S = 0.3  # s a TCP link stays open after the last send before it closes (Link.close)
_BAD_DATA_REASONS = (("Bad prefix", "bad_prefix"), ("invalid MAVLink CRC", "bad_crc"),
                     ("invalid MAVLink message length", "bad_length"), ("invalid incompat_flags", "bad_flags"),
                     ("Invalid signature", "signature"), ("Unable to", "bad_payload"))


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago (for loopback pairs: the demo, the bench, tests)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def parse_connection(conn: str, default_baud: int) -> tuple[str, int]:
    """(device, baud) from a connection string; serial "path:baud" / "path,baud" split off the baud."""
    if not conn or not conn.strip():
        raise ConfigError("--connect: empty connection string")
    conn = conn.strip()
    if conn.startswith(_NETWORK):
        if not re.match(r"^[a-z]+:[^:]+:\d+$", conn):
            raise ConfigError(f"--connect {conn!r}: expected e.g. udpin:0.0.0.0:14550 or tcp:127.0.0.1:5760")
        return conn, default_baud
    m = re.match(r"^(.+?)[:,](\d+)$", conn)
    if m:
        return m.group(1), int(m.group(2))
    return conn, default_baud


class Link:
    """One pymavlink connection with a tlog. sysid 0 = adopt the autopilot's sysid at its first HEARTBEAT.

    `recv(timeout)` returns the messages that arrived (waiting up to `timeout` seconds for the first);
    `send(msg)` packs with our identity, writes and logs. Not thread-safe: use from the daemon loop only.
    signing_key: a key file (or the 32 key bytes): sign what we send, refuse unsigned and wrongly signed input.
    rejected: the Counter refused frames are counted in (shared with the decoders' by the daemon).
    udp_client_timeout_s: on a udpin link, peers not heard from for this long stop being sent to (the last
    one is kept; 0 keeps every peer ever heard, pymavlink's default).
    """

    def __init__(self, conn: str, sysid: int, compid: int, baud: int = 921600, tlog: Path | None = None,
                 wall_clock: Callable[[], float] = time.time, signing_key: Path | bytes | None = None,
                 rejected: Counter[str] | None = None, udp_client_timeout_s: float = 0.0) -> None:
        device, baud = parse_connection(conn, baud)
        key = signing.load_key(signing_key) if isinstance(signing_key, (str, Path)) else signing_key
        self.sysid_fixed = sysid != 0
        try:
            if device.startswith("tcp:"):  # bounded connect attempts (reconnect.py)
                self.conn = open_tcp(device, sysid or 1, compid, "ardupilotmega")
            else:
                self.conn = mavutil.mavlink_connection(device, baud=baud, source_system=sysid or 1,
                                                       source_component=compid, dialect="ardupilotmega",
                                                       autoreconnect=True, udp_timeout=udp_client_timeout_s)
        except ImportError as exc:  # pymavlink imports pyserial only for a serial device
            raise TacoError(f"--connect {conn!r}: a serial link needs pyserial ({exc}); pip install pyserial") from None
        except (OSError, ValueError) as exc:
            raise TacoError(f"--connect {conn!r}: cannot open ({exc})") from None
        self.serial = pace_serial_reconnect(self.conn)  # an unplugged USB device is reopened, not fatal
        self.mav = self.conn.mav
        self.mav.robust_parsing = True
        self._udp = isinstance(self.conn, mavutil.mavudp)
        self._pending: list[Any] = []
        self.rejected: Counter[str] = rejected if rejected is not None else Counter()
        self.guard: signing.SignatureGuard | None = None
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=None)
            self.guard = signing.SignatureGuard(self.mav, key)
        self.tlog = TlogWriter(tlog) if tlog is not None else None
        self.wall_clock = wall_clock
        self.target_system = 0
        self.target_component = 0
        self.sent = 0
        self.received = 0
        self.datagrams = 0  # UDP datagrams read (every one, good or bad)
        log.info("link open: %s (sysid %s, compid %d%s)", conn, sysid or "auto", compid,
                 ", signing" if key is not None else "")

    def fileno(self) -> int | None:
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def recv(self, timeout: float) -> list[Any]:
        """Messages received within `timeout` seconds (all that are already buffered, or the first batch)."""
        out: list[Any] = []
        msg = self._recv_one()
        if msg is None and timeout > 0:
            fd = self.fileno()
            if fd is not None:
                try:
                    select.select([fd], [], [], timeout)
                except (OSError, ValueError):
                    time.sleep(min(timeout, 0.005))
            else:
                time.sleep(min(timeout, 0.002))
            msg = self._recv_one()
        while msg is not None:
            out.append(msg)
            if len(out) >= 500:
                break
            msg = self._recv_one()
        return out

    def _recv_one(self) -> Any:
        """The next accepted message or None; refused frames are counted and skipped (at most _MAX_SKIP in a row,
        so a flood of garbage cannot hold the loop away from its periodic outputs)."""
        for _ in range(_MAX_SKIP):
            try:
                msg = self._next_udp() if self._udp else self.conn.recv_msg()
            except (OSError, ConnectionError) as exc:
                log.warning("link receive error: %s", exc)
                return None
            if msg is None:
                return None
            if self._accept(msg):
                return msg
        return None

    def _next_udp(self) -> Any:
        """The next message of the current datagram, reading one more datagram when it is used up."""
        if self._pending:
            return self._pending.pop(0)
        data = self.conn.recv()
        if not data:
            return None
        self.datagrams += 1
        mav = self.mav
        mav.buf, mav.buf_index, mav.expected_length = bytearray(), 0, mavutil.mavlink.HEADER_LEN_V1 + 2
        msgs = mav.parse_buffer(data) or []
        if mav.buf_len() > 0:  # a frame cut short: never carried over into the next datagram
            self.rejected["MAVLINK:truncated"] += 1
            mav.buf, mav.buf_index = bytearray(), 0
        self._pending = msgs[1:]
        return msgs[0] if msgs else _SKIP  # a datagram without a whole frame

    def _accept(self, msg: Any) -> bool:
        """Count a refused frame (BAD_DATA, unknown id) and say whether to hand `msg` on."""
        if msg is _SKIP:
            return False
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.rejected[self._bad_data_key(msg)] += 1
            return False
        if kind.startswith("UNKNOWN_"):
            self.rejected["MAVLINK:unknown_id"] += 1
            return False
        self.received += 1
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf(), self.wall_clock())
        return True

    def _bad_data_key(self, msg: Any) -> str:
        text = str(getattr(msg, "reason", ""))
        reason = next((key for prefix, key in _BAD_DATA_REASONS if text.startswith(prefix)), "other")
        if reason != "signature":
            return f"MAVLINK:{reason}"
        frame = bytes(msg.data)
        msgid = signing.frame_msgid(frame)
        cls = mavutil.mavlink.mavlink_map.get(msgid) if msgid is not None else None
        name = cls.msgname if cls is not None else "MAVLINK"
        if not signing.frame_is_signed(frame):
            return f"{name}:unsigned"
        return f"{name}:{self.guard.last_reason if self.guard and self.guard.last_reason else 'bad_signature'}"

    def adopt_autopilot(self, msg: Any) -> bool:
        """Take a HEARTBEAT's source as the autopilot (first one only); adopt its sysid unless ours is fixed."""
        if self.target_system:
            return False
        self.target_system = msg.get_srcSystem()
        self.target_component = msg.get_srcComponent()
        if not self.sysid_fixed:
            self.mav.srcSystem = self.target_system
        log.info("autopilot: sysid %d compid %d (autopilot type %d, vehicle type %d); we are %d/%d",
                 self.target_system, self.target_component, msg.autopilot, msg.type, self.mav.srcSystem,
                 self.mav.srcComponent)
        return True

    def send(self, msg: Any) -> None:
        """Pack and send one message (errors are logged, never raised: the loop must keep running)."""
        try:
            buf = msg.pack(self.mav)
            self.conn.write(buf)
            self.mav.seq = (self.mav.seq + 1) % 256
            self.mav.total_packets_sent += 1
            self.mav.total_bytes_sent += len(buf)
        except (OSError, ConnectionError) as exc:
            log.debug("link send error: %s", exc)
            return
        self.sent += 1
        if self.tlog is not None:
            self.tlog.write(buf, self.wall_clock())

    def heartbeat(self) -> None:
        """HEARTBEAT as an onboard controller."""
        m = mavutil.mavlink
        self.send(self.mav.heartbeat_encode(m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0,
                                            m.MAV_STATE_ACTIVE))

    def close(self, linger_s: float = TCP_LINGER_S) -> None:
        """Close the link (and the tlog). A connected TCP link first stays open `linger_s` seconds after the
        last send: ArduPilot SITL's TCP port leaves bytes that arrived with the peer's close unprocessed until
        the next client connects, so a daemon's last GPS_INPUT, applied seconds later by a restarted one's
        connect, threw EKF3 10 m back to where the rover had been (measured in tests/test_sitl.py's daemon restarted
        mid-mission)."""
        if isinstance(self.conn, mavutil.mavtcp) and getattr(self.conn, "port", None) is not None and linger_s > 0:
            time.sleep(linger_s)
        try:
            self.conn.close()
        except OSError:
            pass
        if self.tlog is not None:
            self.tlog.close()


_SKIP = object()  # _next_udp: a datagram without a whole frame
