"""Test tooling, not product code (tests/test_fuzz.py, tests/test_imu_source.py, tools/fuzz_mavlink.py).

Fuzz the daemon over real UDP: a seeded valid autopilot stream mixed with mutated and random MAVLink frames
(fuzz_frames.py), everything the daemon sends back parsed and every float field checked.

One episode per IMU message kind: a Daemon (in this process, its own thread, `udpin` on 127.0.0.1) is started,
fed the valid stream alone until it is anchored (origin + Localiser), then one fuzz frame per 10 ms stream step,
then a clean tail. The sender waits for the daemon to have read what was sent (at most `window` datagrams in
flight), so the kernel does not drop datagrams and every frame is looked at.

    report = run_fuzz(FuzzOptions(frames=5000, seed=0))
    report["crashes"], report["handler_errors"], report["nonfinite_output_fields"], report["rejected_by_reason"]
"""

from __future__ import annotations

import logging
import math
import random
import socket
import threading
import time
from collections import Counter
from dataclasses import asdict, dataclass
from typing import Any, Callable

from fuzz_frames import MUTATIONS, AutopilotStream, Mutator, corrupt_imu, m

from taco_mav.config import Profile, profile_from_dict
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.mavlink.connection import free_udp_port

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FuzzOptions:
    """frames: fuzz frames in all (split evenly over the episodes); seed: every random draw; imu_kinds: one
    episode each; warmup_steps / tail_steps: valid-only 10 ms steps before / after the fuzz; window: datagrams
    in flight at most; output_rate_hz: the daemon's output rate (more outputs checked per second);
    realtime_factor: autopilot seconds per wall second at most (None: as fast as the daemon reads);
    mutations: the mutations drawn from (default: all of fuzz_frames.MUTATIONS); imu_message: the daemon's
    link.imu_message (None: pinned to the episode's kind; "auto": chosen by the daemon from what arrives);
    corrupt_imu_first: IMU messages that decode but are not valid samples (fuzz_frames.corrupt_imu, every IMU
    kind), sent right after the first HEARTBEAT and before any valid IMU sample."""

    frames: int = 5000
    seed: int = 0
    imu_kinds: tuple[str, ...] = ("RAW_IMU", "HIGHRES_IMU", "SCALED_IMU")
    warmup_steps: int = 300
    tail_steps: int = 200
    window: int = 32
    output_rate_hz: float = 20.0
    catch_up_timeout_s: float = 5.0
    realtime_factor: float | None = 10.0
    mutations: tuple[str, ...] = MUTATIONS
    imu_message: str | None = None
    corrupt_imu_first: int = 0


class _Catcher(logging.Handler):
    """Counts log records that carry an exception (any taco_mav logger, any thread)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.count: Counter[str] = Counter()

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info:
            self.count[f"{record.name}: {record.exc_info[0].__name__ if record.exc_info[0] else '?'}"] += 1


class _Outputs:
    """Parses what the daemon sends back (per datagram) and checks every float field."""

    def __init__(self) -> None:
        self.parser = m.MAVLink(None)
        self.parser.robust_parsing = True
        self.by_type: Counter[str] = Counter()
        self.nonfinite: Counter[str] = Counter()
        self.out_of_range: Counter[str] = Counter()
        self.fix_types: Counter[int] = Counter()
        self.timesync_requests: list[Any] = []

    def feed(self, data: bytes) -> None:
        for msg in self.parser.parse_buffer(data) or []:
            kind = msg.get_type()
            self.by_type[kind] += 1
            for name in msg.get_fieldnames():
                values = getattr(msg, name)
                for v in values if isinstance(values, list) else [values]:
                    if isinstance(v, float) and not math.isfinite(v):
                        self.nonfinite[f"{kind}.{name}"] += 1
            if kind in ("GPS_INPUT", "HIL_GPS"):
                if not (abs(msg.lat) <= 900_000_000 and abs(msg.lon) <= 1_800_000_000):
                    self.out_of_range[f"{kind}.latlon"] += 1
            if kind == "GPS_INPUT":
                self.fix_types[msg.fix_type] += 1
                if not 0.0 <= msg.horiz_accuracy <= 1000.0:
                    self.out_of_range["GPS_INPUT.horiz_accuracy"] += 1
            if kind == "TIMESYNC" and msg.tc1 == 0:
                self.timesync_requests.append(msg)


def fuzz_profile(imu_kind: str, output_rate_hz: float) -> Profile:
    """The profile of one episode: emulator matcher (SIMSTATE truth), all three outputs, link.imu_message
    `imu_kind` (a message name, or "auto")."""
    return profile_from_dict({"matcher": "emulator", "link": {"imu_message": imu_kind},
                              "output": {"messages": ["gps_input", "hil_gps", "odometry"],
                                         "rate_hz": output_rate_hz}})


class _Episode:
    """One daemon, one socket, one valid stream, one mutator."""

    def __init__(self, imu_kind: str, seed: int, opt: FuzzOptions) -> None:
        self.opt = opt
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        port = free_udp_port()
        self.daemon = Daemon(fuzz_profile(opt.imu_message or imu_kind, opt.output_rate_hz),
                             DaemonOptions(connect=f"udpin:127.0.0.1:{port}"))
        self.dest = ("127.0.0.1", port)
        self.stream = AutopilotStream(imu_kind)
        self.mutator = Mutator(self.stream, seed, opt.mutations)
        self.outputs = _Outputs()
        self.sent = 0
        self.mutations: Counter[str] = Counter()
        self.stalls = 0
        self.empty = 0
        self.t0_wall, self.t0_stream = time.monotonic(), self.stream.t

    def pace(self) -> None:
        """Sleep while the stream is more than realtime_factor x wall time ahead."""
        if self.opt.realtime_factor is None:
            return
        ahead = (self.stream.t - self.t0_stream) / self.opt.realtime_factor - (time.monotonic() - self.t0_wall)
        if ahead > 0.005:
            time.sleep(ahead)

    def send(self, datagrams: list[bytes], valid: bool) -> None:
        for d in datagrams:
            self.sock.sendto(d, self.dest)
            if d:
                self.sent += 1
            else:
                self.empty += 1  # an empty datagram reads as "nothing there": not counted as sent
            if valid:
                self.mutator.recent.append(d)
        self._drain()
        link = self.daemon.link
        if link is not None and self.sent - link.datagrams >= self.opt.window:
            self._catch_up()

    def _catch_up(self) -> None:
        deadline = time.monotonic() + self.opt.catch_up_timeout_s
        link = self.daemon.link
        assert link is not None
        while self.sent - link.datagrams > self.opt.window // 2:
            if time.monotonic() > deadline or not self.daemon._thread or not self.daemon._thread.is_alive():
                self.stalls += 1
                return
            time.sleep(0.0005)
            self._drain()

    def _drain(self) -> None:
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return
            self.outputs.feed(data)

    def answer_timesync(self) -> None:
        """Answer the daemon's TIMESYNC requests with the stream's clock, as an autopilot does."""
        requests, self.outputs.timesync_requests = self.outputs.timesync_requests, []
        for req in requests:
            self.send([self.stream.pack(self.stream.tx.timesync_encode(int(self.stream.t * 1e9), req.ts1))], True)

    def valid_steps(self, n: int) -> None:
        for _ in range(n):
            self.send(self.stream.step(), True)
            self.answer_timesync()
            self.pace()

    def close(self) -> None:
        self.sock.close()


def _wait(pred: Callable[[], bool], timeout_s: float, ep: _Episode) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        ep.valid_steps(1)
        time.sleep(0.002)
    return pred()


def run_episode(imu_kind: str, frames: int, seed: int, opt: FuzzOptions) -> dict[str, Any]:
    """One daemon fed `frames` fuzz frames around a valid `imu_kind` stream; its figures."""
    ep = _Episode(imu_kind, seed, opt)
    escaped: list[str] = []
    previous_hook = threading.excepthook

    def hook(args: threading.ExceptHookArgs) -> None:
        escaped.append(f"{args.thread.name if args.thread else '?'}: {args.exc_type.__name__}: {args.exc_value}")
        previous_hook(args)

    threading.excepthook = hook
    d = ep.daemon
    try:
        d.start()
        deadline = time.monotonic() + 10.0
        while d.link is None and time.monotonic() < deadline:
            time.sleep(0.01)
        if opt.corrupt_imu_first:  # the autopilot is adopted first, then its IMU messages start corrupt
            ep.send([ep.stream.pack(ep.stream.message("HEARTBEAT"))], True)
            rng = random.Random(seed + 7)
            for _ in range(opt.corrupt_imu_first):
                ep.send([corrupt_imu(ep.stream, rng)], False)
        ep.valid_steps(opt.warmup_steps)
        anchored = _wait(lambda: d.loc is not None, 10.0, ep)
        outputs_before, fix3_before = ep.outputs.by_type["GPS_INPUT"], ep.outputs.fix_types[3]
        for _ in range(frames):
            name, datagrams = ep.mutator.frame()
            ep.mutations[name] += 1
            ep.send(datagrams, False)
            ep.send(ep.stream.step(), True)
            ep.answer_timesync()
            ep.pace()
        ep.valid_steps(opt.tail_steps)
        alive = d._thread is not None and d._thread.is_alive()
        time.sleep(0.3)
        ep._drain()
        d.stop()
        d.join(10.0)
        stopped = d._thread is not None and not d._thread.is_alive()
        ep._drain()  # what the last output slot sent after the drain above (its three messages go out in turn)
    finally:
        threading.excepthook = previous_hook
        ep.close()
    summary = d.summary()
    link = d.link
    return {
        "imu_kind": imu_kind, "fuzz_frames": frames, "datagrams_sent": ep.sent, "empty_datagrams_sent": ep.empty,
        "datagrams_read": link.datagrams if link else 0, "anchored": anchored,
        "crashed": not alive or d.exit_code != 0 or not stopped, "escaped_exceptions": escaped,
        "mutations": dict(ep.mutations), "outputs": dict(ep.outputs.by_type),
        "gps_input_during_fuzz": ep.outputs.by_type["GPS_INPUT"] - outputs_before,
        "gps_input_fix3_during_fuzz": ep.outputs.fix_types[3] - fix3_before,
        "fix_types": {str(k): v for k, v in ep.outputs.fix_types.items()},
        "nonfinite_output_fields": dict(ep.outputs.nonfinite),
        "out_of_range_output_fields": dict(ep.outputs.out_of_range), "sender_stalls": ep.stalls,
        "summary": summary,
    }


def _by_reason(rejected: dict[str, int]) -> dict[str, int]:
    out: Counter[str] = Counter()
    for key, n in rejected.items():
        out[key.rsplit(":", 1)[-1]] += n
    return dict(sorted(out.items()))


def run_fuzz(options: FuzzOptions = FuzzOptions(), progress: bool = False) -> dict[str, Any]:
    """All episodes; the totals the reliability figures are read from (see the module docstring)."""
    catcher = _Catcher()
    root = logging.getLogger("taco_mav")
    level = root.level
    if root.getEffectiveLevel() > logging.ERROR:
        root.setLevel(logging.ERROR)  # exceptions must be logged to be counted
    root.addHandler(catcher)
    episodes = []
    t0 = time.monotonic()
    try:
        n = len(options.imu_kinds)
        for i, kind in enumerate(options.imu_kinds):
            frames = options.frames // n + (1 if i < options.frames % n else 0)
            episodes.append(run_episode(kind, frames, options.seed * 1000 + i, options))
            if progress:
                log.info("fuzz episode %s: %d frames, %s", kind, frames, episodes[-1]["summary"]["dropped"])
    finally:
        root.removeHandler(catcher)
        root.setLevel(level)
    rejected: Counter[str] = Counter()
    totals: dict[str, Counter[str]] = {k: Counter() for k in ("mutations", "outputs", "nonfinite_output_fields",
                                                               "out_of_range_output_fields")}
    for e in episodes:
        rejected.update(e["summary"]["rejected_inputs"])
        for k, c in totals.items():
            c.update(e[k])
    return {
        "options": asdict(options), "wall_s": round(time.monotonic() - t0, 1),
        "fuzz_frames": sum(e["fuzz_frames"] for e in episodes),
        "datagrams_sent": sum(e["datagrams_sent"] for e in episodes),
        "datagrams_read": sum(e["datagrams_read"] for e in episodes),
        "crashes": sum(bool(e["crashed"]) for e in episodes),
        "escaped_exceptions": sum(len(e["escaped_exceptions"]) for e in episodes),
        "handler_errors": sum(e["summary"]["dropped"].get("handler_error", 0) for e in episodes),
        "logged_exceptions": dict(catcher.count),
        "all_anchored": all(e["anchored"] for e in episodes),
        "gps_input_during_fuzz": sum(e["gps_input_during_fuzz"] for e in episodes),
        "gps_input_fix3_during_fuzz": sum(e["gps_input_fix3_during_fuzz"] for e in episodes),
        "imu_sources": {e["imu_kind"]: e["summary"]["sources"]["imu"]["source"] for e in episodes},
        "reboots": sum(e["summary"]["reboots"] for e in episodes),
        "imu_samples": sum(e["summary"]["imu_samples"] for e in episodes),
        "rejected_by_reason": _by_reason(dict(rejected)), "rejected_inputs": dict(sorted(rejected.items())),
        **{k: dict(sorted(c.items())) for k, c in totals.items()},
        "episodes": episodes,
    }
