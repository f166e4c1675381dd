"""Outputs on the autopilot's clock: `ClockRate` (autopilot seconds per companion second from IMU stamps and
their arrival), `AutopilotPeriodic` (a rate in autopilot time scheduled on the companion clock), and the
simulator N times faster than real time WITHOUT lockstep with the daemon on the machine's own clocks (as a
companion beside SITL --speedup runs): GPS_INPUT at output.rate_hz in the autopilot's time."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taco_mav.config import Estimator, load_profile
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.daemon.scheduler import AutopilotPeriodic, Periodic
from taco_mav.mavlink.timesync import ClockMap, ClockRate
from tests.sim_helpers import free_udp_port


def _feed(rate: ClockRate, speed: float, seconds: float, imu_hz: float = 100.0, latency_s: float = 0.003,
          burst_s: float = 0.0, seed: int = 0) -> float:
    """IMU stamps at imu_hz of autopilot time, handled `speed` times faster (companion s = autopilot s / speed)
    plus a random latency (exponential, mean latency_s) and, with burst_s, batches released every burst_s;
    returns the last companion time."""
    rng = np.random.default_rng(seed)
    c = 0.0
    for k in range(int(seconds * speed * imu_hz)):
        a = 100.0 + k / imu_hz
        c = (a - 100.0) / speed + rng.exponential(latency_s)
        if burst_s > 0:
            c = np.ceil(c / burst_s) * burst_s
        rate.add(c, a)
    return c


@pytest.mark.parametrize("speed", [1.5, 2.0, 5.0, 10.0])
def test_clock_rate_at_speed(speed: float) -> None:
    r = ClockRate()
    now = _feed(r, speed, 6.0, seed=int(speed * 10))
    assert r.value(now) == pytest.approx(speed, rel=0.005)


def test_clock_rate_is_exactly_one_on_a_real_vehicle() -> None:
    """1x with a few ms of latency, or with 50 ms radio batches (telemetry radio): exactly 1.0, so the output
    grid is the companion clock's, as before."""
    for kw in ({}, {"burst_s": 0.05, "latency_s": 0.01}):
        r = ClockRate()
        now = _feed(r, 1.0, 6.0, **kw)
        assert r.value(now) == 1.0
    r = ClockRate()
    assert r.value(_feed(r, 1.005, 3.0)) == 1.0  # within 10 %: taken as 1
    r = ClockRate()
    assert r.value(_feed(r, 1.03, 3.0)) == 1.0  # what lockstep's jitter looks like
    r = ClockRate()
    assert r.value(_feed(r, 1.2, 3.0)) == pytest.approx(1.2, rel=0.005)


def test_clock_rate_ignores_a_start_up_stall_and_early_samples() -> None:
    """10 Hz IMU at 1x as the in-process lockstep simulator delivers it: the first 0.6 s of samples handled in
    one batch at 0.55 s (the daemon still starting), and two samples handled 0.1 s BEFORE their stamps (sent just
    before the simulator moved its clock). The former least-squares fit read 3.1, then 1.10-1.17 for 1.5 s (so
    GPS_INPUT went out below 5 Hz of autopilot time); the upper-envelope Theil-Sen fit, with the 1x band
    widened by the arrival jitter over a short span, reads 1 throughout."""
    r = ClockRate()
    seen = []
    for k in range(40):
        a = 100.0 + 0.1 * k
        c = 0.55 + 0.001 * k if k < 6 else a - 100.0
        if k in (12, 17):
            c -= 0.1
        r.add(c, a)
        seen.append(r.value(c))
    known = [v for v in seen if v is not None]
    assert len(known) >= 30 and set(known) == {1.0}


def test_clock_rate_unknown_then_reset() -> None:
    r = ClockRate(min_span_s=0.1)
    assert r.value(0.0) is None
    r.add(0.0, 100.0)
    r.add(0.05, 100.5)
    assert r.value(0.05) is None  # too short a span
    for k in range(2, 40):
        r.add(k * 0.05, 100.0 + k * 0.5)  # 10x
    assert r.value(2.0) == pytest.approx(10.0)
    r.reset()
    assert r.value(2.1) is None
    r2 = ClockRate()
    for k in range(50):
        r2.add(k * 0.01, 100.0 - k * 0.5)  # time running backwards: no plausible rate
    assert r2.value(1.0) is None


def test_clockmap_speed_from_imu_stamps() -> None:
    now = [0.0]
    cm = ClockMap(lambda: now[0])
    assert cm.speed() is None
    for k in range(300):  # 3 s of companion time, 5x
        now[0] = k * 0.01
        cm.on_autopilot_time(50.0 + k * 0.05)
    assert cm.speed() == pytest.approx(5.0, rel=1e-6)
    cm.reset()  # a reboot
    assert cm.speed() is None


def _fires(p: Periodic, seconds: float, seed: int) -> np.ndarray:
    """Companion times at which `p` fires in a loop that wakes at the next due time (plus up to 2 ms) or after
    1-20 ms, whichever is first (the daemon's select timeout)."""
    rng = np.random.default_rng(seed)
    t, out = 0.0, []
    while t < seconds:
        if p.due(t):
            out.append(t)
        t = min(t + rng.uniform(0.001, 0.02), p.next_due + rng.uniform(0.0, 0.002))
    return np.array(out)


@pytest.mark.parametrize("speed", [1.0, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0])
def test_rate_in_autopilot_time_within_two_percent(speed: float) -> None:
    p = AutopilotPeriodic(5.0, 0.0, lambda: speed)
    fired = _fires(p, 60.0 / speed, seed=int(speed))  # 60 s of autopilot time
    t_ap = fired * speed
    rate = (len(t_ap) - 1) / (t_ap[-1] - t_ap[0])
    assert rate == pytest.approx(5.0, rel=0.02)
    assert np.diff(t_ap).max() < 0.245  # ArduPilot's gap rule holds in its own time
    if speed == 1.0:  # unchanged at 1x: the very same schedule as the plain companion-clock grid
        assert np.array_equal(fired, _fires(Periodic(5.0, 0.0), 60.0, seed=1))


def test_unknown_speed_paces_on_the_companion_clock_and_changes_never_burst() -> None:
    speed: list[float | None] = [None]
    p = AutopilotPeriodic(5.0, 0.0, lambda: speed[0])
    assert p.due(0.0) and not p.due(0.1) and p.due(0.2)  # wall pacing while unknown
    speed[0] = 5.0  # now known: 25 Hz on the companion clock from the last slot on
    assert p.due(0.24) and not p.due(0.27) and p.due(0.28)
    assert p.skipped == 0
    assert p.due(1.0)  # a stalled loop: one send, the missed slots skipped (no burst)
    assert p.skipped > 15 and not p.due(1.001)


# ------------------------------------------------------------------------------------------- live

@pytest.fixture(scope="module")
def held_out_world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from taco_mav.datasets.synthetic import build_world

    return build_world(tmp_path_factory.mktemp("world") / "w", seed=11, length_km=0.3, progress=False)


def _beside_a_simulator_process(world: Path, out: Path, speed: float, duration_s: float,
                                score_from_s: float) -> tuple[dict, dict]:
    """The daemon (paper mode, the world's renderer as its camera, on the machine's own clocks) beside `taco-mav
    sim` in its own process, free-running `speed` times faster than real time, as a companion beside SITL
    --speedup, scored from `score_from_s` of drive time; returns (the drive's results.json entry, the daemon
    summary). At 5x an output 9 ms late in wall time already breaks the autopilot's 245 ms rule: in one process
    the simulator's threads shared the daemon's interpreter lock, and the daemon paces on the clock speed it
    learns in its first 0.1-0.3 s, while the simulator's own start is still uneven (3.0, then 4.85, then 4.97):
    two outputs in a row 74-117 ms apart in wall time came there, in a CI run and in 3 of 6 runs here."""
    port = free_udp_port()
    daemon = Daemon(load_profile("synthetic"), DaemonOptions(connect=f"udpin:127.0.0.1:{port}",
                                                             camera=f"world:{world}", estimator=Estimator.PAPER))
    daemon.start()
    try:
        sim = subprocess.run([sys.executable, "-m", "taco_mav.cli", "sim", "--drive", str(world), "--connect",
                              f"udpout:127.0.0.1:{port}", "--out", str(out), "--speed", str(speed), "--duration",
                              str(duration_s), "--wait", "10", "--score-from", str(score_from_s)],
                             capture_output=True, text=True, timeout=180)
    finally:
        daemon.stop()
        daemon.join(5.0)
    assert sim.returncode == 0, sim.stderr[-2000:]
    (seq,) = json.loads((out / "results.json").read_text())["sequences"].values()
    return seq, daemon.summary()


def test_sim_speed_5_without_lockstep(held_out_world: Path, tmp_path: Path) -> None:
    """The simulator 5x faster than real time, free-running; the daemon on time.monotonic / time.time (not the
    simulator's clock), classical matcher on rendered frames: after 2 s of drive time (0.4 s of wall time) to
    learn the clock, 5 Hz and ArduPilot's gap rules in autopilot time, ATE <= 5 m."""
    seq, summary = _beside_a_simulator_process(held_out_world, tmp_path / "sim", speed=5.0, duration_s=40.0,
                                               score_from_s=2.0)
    assert summary["clock_speed"] == pytest.approx(5.0, rel=0.01)
    assert seq["gps_input_rate_hz"] == pytest.approx(5.0, rel=0.02), seq["gps_input_rate_hz"]
    assert seq["gps_input_interval_avg_ms"] < 215.0 and seq["consecutive_gaps_over_245ms"] == 0
    # Free-running, a trigger's answer is as late as the machine is slow, x5 in autopilot time, and paper mode's
    # 1-sigma passes output.degrade_accuracy_m meanwhile: fix type 1 then is the honest report. Idle 99 %
    # are 3D, the CI machine gave 95 %, two busy processes beside the test 84 %; a wrong clock gives far fewer.
    assert seq["fix_type_counts"].get("3", 0) >= 0.8 * seq["gps_input_count"]
    assert seq["ate_m"] <= 5.0
    assert summary["fixes"].get("accepted", 0) >= 5 and summary["imu_gaps"] == 0
