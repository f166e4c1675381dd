"""Faults in closed loop on ArduPilot Rover SITL (docs/sitl.md): what a mission with `fault=KIND` (`taco-mav mission
--fault KIND`, `tools/sitl_mission.py --fault KIND`) does to the rover while it runs, `fault_after_s` seconds after
AUTO.

- `camera`: the daemon's camera frames frozen for 10 s, then black for 10 s (`world:DIR?faults=FILE`,
  taco_mav/datasets/synthetic/world_faults.py);
- `stall`: the matcher's worker stalls for 30 s (the frame fetch it makes blocks once; the daemon's
  matcher_timeout_s, 10 s, abandons it and starts a fresh worker);
- `link`: the link between the daemon and the autopilot cut for 5 s (a TCP relay in between drops every byte both
  ways, as a serial cable pulled and pushed back);
- `glitch` (hand-over set-up): SITL's GNSS (GPS1, steering the rover) jumps 20 m north-east for 30 s
  (SIM_GPS1_GLTCH_X/Y, in degrees);
- `spoof` (hand-over set-up): SITL's GNSS dragged away east at 0.5 m/s for 40 s (20 m), then released.
"""

from __future__ import annotations

import json
import math
import selectors
import socket
import threading
import time
from pathlib import Path
from typing import Any

from taco_mav.closedloop.scoring import daemon_summary

KINDS = ("camera", "stall", "link", "glitch", "spoof")
CAMERA_FREEZE_S = CAMERA_BLACK_S = 10.0
STALL_S = 30.0
LINK_CUT_S = 5.0
GLITCH_M, GLITCH_S = 20.0, 30.0
SPOOF_MPS, SPOOF_S = 0.5, 40.0
EARTH_M_PER_DEG = 6378137.0 * math.pi / 180.0


class LinkRelay:
    """A TCP relay on a free local port to `target_port` (SITL's SERIAL1): the daemon connects here. `cut(s)` drops
    every byte both ways for s seconds; the TCP connections stay up, so the daemon sees silence, not a close.

    A client that connects before the autopilot listens (SITL opens SERIAL1 only after its SERIAL0 has a ground
    station, later still on a loaded machine) is held, connected, and the upstream connect is tried again every
    `RETRY_S` for up to `UPSTREAM_WAIT_S`, as a serial cable is there before the autopilot has booted: closing it
    at once would test the daemon's reconnect at start-up, which is not the fault asked for."""

    RETRY_S = 0.5
    UPSTREAM_WAIT_S = 60.0

    def __init__(self, target_port: int) -> None:
        self.target_port = target_port
        self._listen = socket.socket()
        self._listen.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listen.bind(("127.0.0.1", 0))
        self._listen.listen(4)
        self.port = self._listen.getsockname()[1]
        self._cut_until = 0.0
        self.dropped_bytes = 0
        self.upstream_refusals = 0  # upstream connects refused while a client waited (start-up)
        self.clients = 0
        self._pending: list[tuple[socket.socket, float]] = []  # clients waiting for the autopilot, since
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="link-relay", daemon=True)
        self._thread.start()

    def cut(self, seconds: float) -> None:
        self._cut_until = time.monotonic() + seconds

    def _connect_pending(self, sel: selectors.BaseSelector) -> None:
        """Try the upstream connect for each waiting client; give a client up after UPSTREAM_WAIT_S."""
        waiting = []
        for client, since in self._pending:
            try:
                upstream = socket.create_connection(("127.0.0.1", self.target_port), timeout=2)
            except OSError:
                self.upstream_refusals += 1
                if time.monotonic() - since < self.UPSTREAM_WAIT_S:
                    waiting.append((client, since))
                else:
                    client.close()
                continue
            sel.register(client, selectors.EVENT_READ, upstream)
            sel.register(upstream, selectors.EVENT_READ, client)
        self._pending = waiting

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._listen, selectors.EVENT_READ, None)
        last_try = 0.0
        while not self._stop.is_set():
            if self._pending and time.monotonic() - last_try >= self.RETRY_S:
                last_try = time.monotonic()
                self._connect_pending(sel)
            for key, _ in sel.select(timeout=0.2):
                if key.data is None:  # a new client: connect it through (now, or once the autopilot listens)
                    client, _ = self._listen.accept()
                    self.clients += 1
                    self._pending.append((client, time.monotonic()))
                    last_try = time.monotonic()
                    self._connect_pending(sel)
                    continue
                src, dst = key.fileobj, key.data
                try:
                    data = src.recv(65536)
                except OSError:
                    data = b""
                if not data:
                    for s in (src, dst):
                        try:
                            sel.unregister(s)
                        except (KeyError, ValueError):
                            pass
                        s.close()
                    continue
                if time.monotonic() < self._cut_until:
                    self.dropped_bytes += len(data)
                    continue
                try:
                    dst.sendall(data)
                except OSError:
                    pass
        for client, _ in self._pending:
            client.close()
        sel.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._listen.close()


class FaultRun:
    """One fault on cue in a mission (see the module docstring). `step(t)` is called every loop with the wall
    seconds since AUTO; `figures()` says when the fault was applied and removed."""

    def __init__(self, kind: str, after_s: float, out: Path, gcs: Any, home: tuple[float, ...], setup: str) -> None:
        if kind not in KINDS:
            raise ValueError(f"fault {kind!r}: one of {', '.join(KINDS)}")
        if kind in ("glitch", "spoof") and setup != "handover":
            raise ValueError(f"fault {kind!r} needs the hand-over set-up (SITL's GNSS steering the rover)")
        self.kind, self.after_s, self.gcs, self.home = kind, after_s, gcs, home
        self.cue = out / "camera_faults.json"
        self.cue.unlink(missing_ok=True)
        self.relay: LinkRelay | None = None
        self.started: float | None = None
        self.ended: float | None = None
        self._phase = ""
        self._last_spoof_t = -1.0

    def camera(self, world: Path) -> str:
        """The daemon's --camera: the world, with the cue file for camera faults."""
        return f"world:{world}?faults={self.cue}" if self.kind in ("camera", "stall") else f"world:{world}"

    def connect_port(self, sitl_port: int) -> int:
        """The port the daemon connects to: a relay for link cuts, else SITL's own."""
        if self.kind != "link":
            return sitl_port
        self.relay = LinkRelay(sitl_port)
        return self.relay.port

    def _camera_cue(self, **data: Any) -> None:
        tmp = self.cue.with_suffix(".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(self.cue)

    def _gnss_offset(self, east_m: float, north_m: float) -> None:
        self.gcs.set_param("SIM_GPS1_GLTCH_X", north_m / EARTH_M_PER_DEG)
        self.gcs.set_param("SIM_GPS1_GLTCH_Y", east_m / (EARTH_M_PER_DEG * math.cos(math.radians(self.home[0]))))

    def step(self, t: float) -> None:
        if t < self.after_s or self.ended is not None:
            return
        since = t - self.after_s
        if self.started is None:
            self.started = t
        k = self.kind
        if k == "camera":
            phase = ("freeze" if since < CAMERA_FREEZE_S else
                     "black" if since < CAMERA_FREEZE_S + CAMERA_BLACK_S else "none")
            if phase != self._phase:
                self._camera_cue(mode=phase)
                self._phase = phase
            if phase == "none":
                self.ended = t
        elif k == "stall":
            self._camera_cue(mode="stall", seconds=STALL_S, id=1, thread="taco-matcher")
            self.ended = t + STALL_S
        elif k == "link":
            assert self.relay is not None
            self.relay.cut(LINK_CUT_S)
            self.ended = t + LINK_CUT_S
        elif k == "glitch":
            if since < GLITCH_S:
                if not self._phase:
                    d = GLITCH_M / math.sqrt(2.0)
                    self._gnss_offset(d, d)
                    self._phase = "on"
            else:
                self._gnss_offset(0.0, 0.0)
                self.ended = t
        elif k == "spoof":
            if since < SPOOF_S:
                if since - self._last_spoof_t >= 1.0:  # drag it a little further each second
                    self._gnss_offset(SPOOF_MPS * since, 0.0)
                    self._last_spoof_t = since
            else:
                self._gnss_offset(0.0, 0.0)
                self.ended = t

    def figures(self, daemon_dir: Path) -> dict[str, Any]:
        """When the fault was on (s after AUTO), and what the daemon made of it (`daemon_summary`)."""
        out: dict[str, Any] = {"fault": self.kind, "fault_started_after_auto_s": self.started,
                               "fault_ended_after_auto_s": self.ended}
        if self.relay is not None:
            out["fault_link_dropped_bytes"] = self.relay.dropped_bytes
            out["fault_link_clients"] = self.relay.clients
            out["fault_link_upstream_refusals"] = self.relay.upstream_refusals
        out.update(daemon_summary(daemon_dir))
        return out

    def close(self) -> None:
        if self.relay is not None:
            self.relay.close()
