"""The daemon over a serial device: a real pseudo-terminal pair (os.openpty), the daemon on the slave end as
`--connect PATH:921600` (PATH a symlink we control, as udev's /dev/serial/by-id/... is), the minimal autopilot
(tests/mav_autopilot.py) on the master end. Unplugging (closing the master, removing the device path) and
plugging back (a new pty at the same path) must look like a dropped UDP link: outage reported, port reopened,
outputs resumed, no traceback."""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import time
import tty
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from mav_autopilot import MiniAutopilot, link_test_profile
from pymavlink import mavutil

from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.errors import TacoError
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.reconnect import pace_serial_reconnect

BAUD = 921600


class PtyEnd(mavutil.mavfile):
    """The autopilot's end of a fresh pseudo-terminal pair (the master side, non-blocking); `path` is made a
    symlink to the slave device (/dev/pts/N), replacing whatever was there. close() unplugs: the master and
    our slave descriptor are closed (the daemon's reads and writes then fail) and the path removed."""

    def __init__(self, path: Path) -> None:
        mavutil.set_dialect("ardupilotmega")
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # raw before anyone writes: no echo, no CR/LF translation
        os.set_blocking(self.master, False)
        self.path = path
        tmp = path.with_name(path.name + ".new")
        tmp.unlink(missing_ok=True)
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, path)
        super().__init__(self.master, str(path), source_system=1, source_component=1)

    def recv(self, n: int | None = None) -> bytes:
        try:
            return os.read(self.master, n or 1024)
        except OSError as exc:  # EAGAIN: nothing there; EIO: no slave open
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return b""
            raise

    def write(self, buf: bytes) -> int:
        try:
            return os.write(self.master, bytes(buf))
        except BlockingIOError:
            return 0  # the daemon is not reading: the tty buffer is full, drop

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self.path.unlink(missing_ok=True)


@dataclass
class PtyAutopilot(MiniAutopilot):
    """MiniAutopilot on a pseudo-terminal whose slave is reachable at `device`; its `outage` unplugs it."""

    device: Path = Path("/nonexistent")

    def _open(self):
        return PtyEnd(self.device)


class Tracebacks(logging.Handler):
    """Counts log records that carry an exception, from any logger."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info:
            self.records.append(f"{record.name}: {record.getMessage()}")


def _drive(tmp_path: Path, drive_s: float, **fault) -> tuple[Daemon, PtyAutopilot, list[str]]:
    device = tmp_path / "ttyTACO"
    ap = PtyAutopilot(0, device=device, gps_s=1.5, **fault)  # the pty exists before the daemon opens it
    catcher = Tracebacks()
    logging.getLogger().addHandler(catcher)
    try:
        daemon = Daemon(link_test_profile(),
                        DaemonOptions(connect=f"{device}:{BAUD}", log_dir=tmp_path / "log"))
        daemon.start()
        ap.start()
        time.sleep(drive_s)
        daemon.stop()
        daemon.join(5.0)
        ap.stop()
    finally:
        logging.getLogger().removeHandler(catcher)
    return daemon, ap, catcher.records


def test_serial_pty_end_to_end(tmp_path: Path) -> None:
    daemon, ap, tracebacks = _drive(tmp_path, 6.0)
    link = daemon.link
    assert link is not None and link.serial and isinstance(link.conn, mavutil.mavserial)
    assert link.conn.baud == BAUD and link.conn.device == str(tmp_path / "ttyTACO")
    assert daemon.exit_code == 0 and not tracebacks
    got = ap.of_type("GPS_INPUT")
    times = np.array([r.t for r in got])
    assert len(times) >= 20
    rate = (len(times) - 1 + daemon.summary()["output_slots_skipped"]) / (times[-1] - times[0])
    assert rate >= 4.9, rate
    assert all(r.msg.fix_type == 3 for r in got[2:])
    assert {"GPS1_TYPE"} <= set(ap.params_asked) and ap.commands  # requests went out over the serial line
    last = got[-1]
    lat, lon = ap.truth_latlon(last.t - ap.t_start)
    dn = (last.msg.lat * 1e-7 - lat) * 111_320.0
    de = (last.msg.lon * 1e-7 - lon) * 111_320.0 * math.cos(math.radians(lat))
    assert math.hypot(dn, de) < 2.0


def test_unplugged_serial_is_reopened(tmp_path: Path) -> None:
    """Unplugged from 2 s to 6 s (link.timeout_s is 3 s): link lost, then restored when the device is back at
    the same path; nothing reaches the autopilot meanwhile; 5 Hz resumes after it."""
    outage = (2.0, 6.0)
    daemon, ap, tracebacks = _drive(tmp_path, 10.0, outage=outage)
    s = daemon.summary()
    assert daemon.exit_code == 0 and not tracebacks, tracebacks
    assert s["link_outages"] == 1 and not s["link_lost"] and s["imu_gaps"] == 1
    assert daemon.link is not None and not daemon.link.conn.portdead
    events = [json.loads(line) for line in (tmp_path / "log" / "events.jsonl").read_text().splitlines()]
    restored = [e for e in events if e["event"] == "link_restored"]
    assert len(restored) == 1 and 3.5 < restored[0]["outage_s"] < 5.5
    gps = ap.of_type("GPS_INPUT")
    el = np.array([r.t - ap.t_start for r in gps])
    assert not np.any((el > outage[0] + 0.1) & (el < outage[1]))
    back = el[el >= outage[1]]
    assert len(back) >= 5 * (10.0 - outage[1]) - 8  # reopened within about a second, then 5 Hz
    assert np.all(np.diff(back[2:]) < 0.3)
    assert any(r.msg.text.startswith("TACO: link restored") for r in ap.of_type("STATUSTEXT"))


def test_serial_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(TacoError, match="cannot open"):
        Link(f"{tmp_path / 'absent'}:{BAUD}", 1, 191)
    end = PtyEnd(tmp_path / "tty0")
    try:
        link = Link(f"{end.path},57600", 1, 191)  # "path,baud" too
        assert link.serial and link.conn.port.baudrate == 57600
        end.close()  # unplugged: reads give nothing, writes are dropped, no exception
        assert link.recv(0.01) == []
        link.heartbeat()
        assert link.conn.portdead and link.fileno() is None
        link.recv(0.0)  # a reopen attempt: the path is gone
        end = PtyEnd(tmp_path / "tty0")  # back at the same path: reopened at the next paced attempt (1 s)
        link.recv(0.0)
        assert link.conn.portdead
        time.sleep(1.0)
        link.recv(0.0)
        assert not link.conn.portdead and link.conn.port.baudrate == 57600
        link.heartbeat()
        time.sleep(0.05)
        msg = end.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
        assert msg is not None and msg.get_srcComponent() == 191
        link.close()
    finally:
        end.close()
    udp = mavutil.mavlink_connection("udpin:127.0.0.1:0")
    assert not pace_serial_reconnect(udp)  # only serial connections are changed
    udp.close()
