"""Where the daemon's origin comes from, end to end: the simulator (ArduPilot's GPS1/GPS2 model) and
the real daemon in one process over UDP on 127.0.0.1, the daemon on the simulator's clock (as tests/test_live.py).

- no --origin, no GNSS at all: the origin is the EKF origin (GPS_GLOBAL_ORIGIN), and the run meets the rate
  rules and ATE <= 1 m (taco+, classical matcher on a synthetic world, lockstep 5x);
- our own instance (GPS1_TYPE 14) reports a 3D fix, but is never read as GNSS, before or without the
  parameter answer; with nothing offered, the "no origin" STATUSTEXTs every 10 s;
- GPS1 a real receiver, the daemon GPS2 (output.gps_id 1): origin from GPS_RAW_INT, GPS_INPUT kept on instance 1;
- a fuzzed GPS_RAW_INT / GPS2_RAW stream changes counters only;
- with the Localiser's GNSS fusion: GNSS fused then lost (`gnss_lost`), spoofing reported (`gnss_rejected`).
"""

from __future__ import annotations

import json
import math
import random
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as apm

from taco_mav.config import Estimator, load_profile, profile_from_dict, replace_in
from taco_mav.daemon.daemon import Daemon, DaemonOptions
from taco_mav.sim import Simulator
from taco_mav.sim.clock import SimClock
from tests.sim_helpers import free_udp_port

GNSS_EVENTS = ("gnss_lost", "gnss_back", "gnss_rejected", "gnss_accepted_again", "start_from_gnss")


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from taco_mav.datasets.synthetic import build_world

    return build_world(tmp_path_factory.mktemp("world") / "w", seed=1, length_km=0.3, progress=False)


def _events(log_dir: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (log_dir / "events.jsonl").read_text().splitlines()]


def _live(world: Path, log_dir: Path, *, gps_id: int = 0, during: Any = None, shadow: bool = False,
          **sim_kw: Any) -> tuple[dict[str, Any], Daemon, Simulator]:
    """The full drive, lockstep 5x, taco+ on the synthetic profile with frames rendered at the true pose;
    `during(daemon, port)` runs in a thread while it plays."""
    port = free_udp_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=5.0, lockstep=True, wait_companion_s=10.0, drain_s=0.3,
                    **sim_kw)
    prof = replace_in(load_profile("synthetic"), "output.gps_id", gps_id)
    daemon = Daemon(prof, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}", log_dir=log_dir,
                                        estimator=Estimator.TACO_PLUS, shadow=shadow), clock=sim.clock,
                    wall_clock=sim.utc_now)
    daemon.start()
    extra = threading.Thread(target=during, args=(daemon, port), daemon=True) if during else None
    try:
        sim.start()
        if extra is not None:
            extra.start()
        assert sim.join(timeout=120.0), "simulator did not finish"
    finally:
        daemon.stop()
        daemon.join(5.0)
        if extra is not None:
            extra.join(5.0)
    return sim.results()["sequences"][sim.drive.name], daemon, sim


def _assert_rate(seq: dict[str, Any]) -> None:
    assert seq["gps_input_rate_hz"] >= 4.9 and seq["consecutive_gaps_over_245ms"] == 0
    assert seq["gps_input_dropped_wrong_id"] == 0 and not seq["gps_timeout"]


@pytest.fixture(scope="module")
def no_gnss(world: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Daemon, Simulator, Path]:
    log_dir = tmp_path_factory.mktemp("no_gnss")
    seq, daemon, sim = _live(world, log_dir, deny_after_s=0.0)
    return seq, daemon, sim, log_dir


def test_origin_from_ekf_origin_without_gnss(no_gnss) -> None:
    """--deny-after 0, GPS1_TYPE 14, no --origin: the EKF origin starts it; our echo on GPS_RAW_INT is ignored."""
    seq, daemon, sim, log_dir = no_gnss
    events = _events(log_dir)
    origins = [e for e in events if e["event"] == "origin"]
    assert [e["source"] for e in origins] == ["GPS_GLOBAL_ORIGIN"]
    assert (origins[0]["lat"], origins[0]["lon"]) == (pytest.approx(sim.home[0]), pytest.approx(sim.home[1]))
    _assert_rate(seq)
    assert seq["ate_m"] <= 1.0 and seq["length_km"] > 0.4
    assert seq["ate_denied_m"] == seq["ate_m"] and seq["denied_from_s"] == 0.0
    g = daemon.gnss.summary()
    assert sim.echo.state().fix_type == 3  # GPS1 reported our own 3D fix back ...
    assert g["gps1_ours"] >= 100 and g["state"] == "none" and "gps1_fix" not in g  # ... and it was never GNSS
    assert g["gps2_no_fix"] >= 100 and daemon.params_check.types == {1: 14, 2: 1}
    assert not [e for e in events if e["event"] in GNSS_EVENTS + ("no_origin", "param_check")]


def _inject_gps_input(sim: Simulator, stop: threading.Event) -> None:
    """Another GPS_INPUT source (gps_id 0, the drive's start, 3D) into the simulator, so GPS1 echoes a fix."""
    while sim._conn is None and not stop.is_set():
        time.sleep(0.01)
    sim_addr = sim._conn.port.getsockname()
    tx = apm.MAVLink(None, srcSystem=1, srcComponent=192)
    lat, lon = int(sim.drive.true_lat[0] * 1e7), int(sim.drive.true_lon[0] * 1e7)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        while not stop.wait(0.04):
            msg = tx.gps_input_encode(0, 0, 0, 0, 0, 3, lat, lon, 115.0, 0.8, 0.8, 0, 0, 0, 0.3, 1.0, 1.0, 10, 0)
            s.sendto(msg.pack(tx), ("127.0.0.1", sim_addr[1]))


@pytest.mark.parametrize("check_params", [True, False], ids=["params_answered", "params_unknown"])
def test_origin_never_from_own_instance_and_no_origin_notice(world: Path, tmp_path: Path,
                                                             check_params: bool) -> None:
    """GPS1 (type 14, ours) reports a 3D fix from someone's GPS_INPUT; no EKF origin, home or real GNSS: the
    daemon never takes an origin, sends nothing, and says every 10 s (autopilot clock) how to give one."""
    port = free_udp_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=5.0, duration_s=26.0, wait_companion_s=10.0,
                    drain_s=0.3, deny_after_s=0.0, send_home=False)
    prof = profile_from_dict({"matcher": "emulator", "link": {"check_params": check_params}})
    daemon = Daemon(prof, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", log_dir=tmp_path), clock=sim.clock,
                    wall_clock=sim.utc_now)
    stop = threading.Event()
    injector = threading.Thread(target=_inject_gps_input, args=(sim, stop), daemon=True)
    daemon.start()
    try:
        sim.start()
        injector.start()
        assert sim.join(timeout=60.0)
    finally:
        stop.set()
        daemon.stop()
        daemon.join(5.0)
        injector.join(2.0)
    assert sim.echo.state().fix_type == 3
    g = daemon.gnss.summary()
    assert daemon.origin is None and daemon.summary()["outputs"] == 0 and g["gps1_ours"] >= 40
    assert g["state"] == "none" and (daemon.params_check is None) is (not check_params)
    texts = [t for _, _, t in sim.statustexts]
    assert texts.count("TACO: no origin: set EKF origin/home in the GCS") == 3  # 3, 13, 23 s after the HEARTBEAT
    assert texts.count("TACO: or --origin LAT,LON[,ALT] or a GNSS 3D fix") == 3
    assert [e["notices"] for e in _events(tmp_path) if e["event"] == "no_origin"] == [1, 2, 3]
    assert daemon.origins.request.sent >= 2 * 10  # GPS_GLOBAL_ORIGIN + HOME_POSITION every 2 s


def test_gps1_real_receiver_daemon_gps2(world: Path, tmp_path: Path) -> None:
    """--gps1-type 1, output.gps_id 1, no home: the origin is GPS1's fix (GPS_RAW_INT), the simulator keeps our
    GPS_INPUT on instance 1 and reports it on GPS2_RAW, which the daemon never reads as GNSS."""
    seq, daemon, sim = _live(world, tmp_path, gps_id=1, gps1_type=1, send_home=False, duration_s=40.0)
    origins = [e for e in _events(tmp_path) if e["event"] == "origin"]
    assert [e["source"] for e in origins] == ["GPS_RAW_INT"]
    _assert_rate(seq)
    assert sim.monitor.instance == 1 and seq["gps_input_count"] >= 190 and seq["ate_m"] <= 1.5
    assert daemon.params_check.types == {1: 1, 2: 14} and not daemon.params_check.warnings
    g = daemon.gnss.summary()
    assert g["gps2_ours"] >= 50 and g["gps1_fix"] >= 2 and g["instance"] == 1
    assert sim.echo.state().fix_type == 3


def _fuzz_gnss(daemon: Daemon, port: int) -> None:
    """Once the daemon has its origin: 600 GPS_RAW_INT / GPS2_RAW frames from the autopilot's identity (random
    fields, fix types flapping, absurd values at the right place, a confident fix 500 km away), 200 per second."""
    deadline = time.monotonic() + 30.0
    while daemon.origin is None and time.monotonic() < deadline:
        time.sleep(0.01)
    rnd = random.Random(14)
    tx = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    lat0, lon0 = int(daemon.origin.lat * 1e7), int(daemon.origin.lon * 1e7)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for k in range(600):
            kind = k % 5
            fix, lat, lon, alt, vel, cog, h_acc = 3, lat0, lon0, 115_000, 500, 9000, 800
            if kind == 0:  # anything
                fix, lat, lon = rnd.randint(0, 255), rnd.randint(-2**31, 2**31 - 1), rnd.randint(-2**31, 2**31 - 1)
                alt, vel, cog, h_acc = rnd.randint(-2**31, 2**31 - 1), rnd.randint(0, 65535), rnd.randint(0, 65535), \
                    rnd.randint(0, 2**32 - 1)
            elif kind == 1:  # fix type flapping, no position
                fix, lat, lon = rnd.choice([0, 1, 2, 3, 6]), 0, 0
            elif kind == 2:  # absurd values at the right place
                alt, vel, h_acc = rnd.choice([(2**31 - 1, 500, 800), (115_000, 65534, 800), (115_000, 500, 2**32 - 1)])
            elif kind == 3:  # a confident fix 500 km away
                lat = lat0 + 45_000_000
            else:
                fix, cog = 255, 40000
            t_us = rnd.randint(0, 2**64 - 1)
            if rnd.random() < 0.5:
                msg = tx.gps_raw_int_encode(t_us, fix, lat, lon, alt, 80, 120, vel, cog, 12, 0, h_acc, 0, 0, 0)
            else:
                msg = tx.gps2_raw_encode(t_us, fix, lat, lon, alt, 80, 120, vel, cog, 12, 0, 0, 0, 0, h_acc, 0, 0, 0)
            s.sendto(msg.pack(tx), ("127.0.0.1", port))
            time.sleep(0.005)


def test_fuzzed_gnss_changes_only_counters(world: Path, tmp_path: Path, no_gnss) -> None:
    """The no-GNSS run again with garbage GPS_RAW_INT / GPS2_RAW injected: refused by the decoders or the
    tracker (counted), no GNSS state, no event, the same origin and the same accuracy as without."""
    seq, daemon, _ = _live(world, tmp_path, deny_after_s=0.0, during=_fuzz_gnss)
    clean = no_gnss[0]
    events = _events(tmp_path)
    assert [e["source"] for e in events if e["event"] == "origin"] == ["GPS_GLOBAL_ORIGIN"]
    assert not [e for e in events if e["event"] in GNSS_EVENTS]
    g = daemon.gnss.summary()
    rejected = {k: v for k, v in daemon.summary()["rejected_inputs"].items() if k.startswith("GPS2_RAW:")}
    assert g["state"] == "none" and g.get("far_from_origin", 0) >= 30
    assert set(rejected) >= {"GPS2_RAW:no_3d_fix", "GPS2_RAW:position_range", "GPS2_RAW:fix_type_range",
                             "GPS2_RAW:alt_range", "GPS2_RAW:speed_range", "GPS2_RAW:accuracy_range"}
    assert g["gps1_ours"] >= no_gnss[1].gnss.summary()["gps1_ours"] + 200  # GPS1 fuzz: ours, only counted
    assert sum(rejected.values()) + g.get("far_from_origin", 0) >= 250 + no_gnss[1].gnss.summary()["gps2_no_fix"]
    _assert_rate(seq)
    assert seq["ate_m"] <= 1.0 and abs(seq["ate_m"] - clean["ate_m"]) < 0.2


def test_gnss_fused_then_lost(world: Path, tmp_path: Path) -> None:
    """GNSS (GPS2, 1.5 m white + wandering bias) for 40 s, then NO_FIX: fused while there, `gnss_lost` and a
    WARNING STATUSTEXT 1 s after it goes, and the denied span stays accurate."""
    seq, daemon, sim = _live(world, tmp_path, deny_after_s=40.0, gnss_noise_m=1.5, seed=2)
    lost = [e for e in _events(tmp_path) if e["event"] in GNSS_EVENTS]
    assert [(e["event"], e["instance"], e["reason"]) for e in lost] == [("gnss_lost", 2, "no_3d_fix")]
    assert [(s, t) for _, s, t in sim.statustexts if "GPS2" in t] == [(4, "TACO: GPS2 lost (no 3d fix): camera+IMU")]
    g = daemon.gnss.summary()
    assert g["outcome_fused"] >= 60 and g["state"] == "lost"
    _assert_rate(seq)
    # the estimator's own figure (required: <= 0.6 m after 60 s of GNSS) is the core's to pin down; here
    # the denied span only has to stay at the no-GNSS run's level
    assert seq["denied_from_s"] == 40.0 and seq["ate_denied_m"] <= 1.0 and seq["ekf_gate_pass_fraction"] >= 0.95


def test_spoofing_reported(world: Path, tmp_path: Path) -> None:
    """From 30 s the receiver keeps a confident fix while dragged north-east at 0.5 m/s: `gnss_rejected` (once,
    with the guard's figures) and a WARNING STATUSTEXT; our output stays within 5 m of the truth."""
    seq, daemon, sim = _live(world, tmp_path, deny_after_s=float("inf"), gnss_noise_m=1.5, seed=2,
                             spoof_after_s=30.0, spoof_drift_mps=0.5, spoof_bearing_deg=45.0)
    events = [e for e in _events(tmp_path) if e["event"] in GNSS_EVENTS]
    assert [e["event"] for e in events] == ["gnss_rejected"] and events[0]["instance"] == 2
    assert 0.0 < events[0]["innovation_m"] < 10.0 and events[0]["window_nis"] > 0.0
    warn = [t for _, s, t in sim.statustexts if s == 4 and "GPS2 REJECTED" in t]
    assert len(warn) == 1 and daemon.gnss.summary()["rejecting"]
    _assert_rate(seq)
    assert seq["max_error_m"] <= 5.0 and seq["denied_from_s"] == 30.0


def test_restart_mid_drive_starts_where_the_autopilot_is(world: Path, tmp_path: Path) -> None:
    """A daemon stopped mid-drive and started again with the same command (no --origin, no GNSS, the EKF origin
    set): the new one starts where the autopilot's own position (GLOBAL_POSITION_INT) puts the vehicle, moving,
    with a 1-sigma of at least 3 m, never at the origin (a daemon that starts at the origin, at rest, reports
    TRACKING 45 m from the rover); no report of either run is more than 5 m from the truth."""
    port = free_udp_port()
    sim = Simulator(world, f"udpout:127.0.0.1:{port}", speed=5.0, lockstep=True, wait_companion_s=10.0, drain_s=0.3,
                    deny_after_s=0.0)
    prof = load_profile("synthetic")

    def daemon(log_dir: Path) -> Daemon:
        return Daemon(prof, DaemonOptions(connect=f"udpin:127.0.0.1:{port}", camera=f"world:{world}", log_dir=log_dir,
                                          estimator=Estimator.TACO_PLUS), clock=sim.clock, wall_clock=sim.utc_now)

    first = daemon(tmp_path / "first")
    first.start()
    try:
        sim.start()
        deadline = time.monotonic() + 60.0
        while (sim.play_start is None or sim.clock.now() - sim.play_start < 20.0) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        first.stop()
        first.join(5.0)
    second = daemon(tmp_path / "second")
    second.start()
    try:
        assert sim.join(timeout=120.0), "simulator did not finish"
    finally:
        second.stop()
        second.join(5.0)
    seq = sim.results()["sequences"][sim.drive.name]
    starts = [e for e in _events(tmp_path / "second") if e["event"] == "start_from_autopilot"]
    assert len(starts) == 1 and starts[0]["sigma_h_m"] >= 3.0 and starts[0]["speed"] > 1.0
    assert math.hypot(starts[0]["x"], starts[0]["y"]) > 50.0  # far from the origin, where it would have started
    assert not [e for e in _events(tmp_path / "first") if e["event"] == "start_from_autopilot"]  # a fresh start
    assert second.summary()["dropped"].get("imu_before_start", 0) <= 10  # it waited at most for one answer
    assert seq["max_error_m"] <= 5.0 and seq["ate_m"] <= 1.5


def test_shadow_twin_measures_its_error_while_gnss_is_honest(world: Path, tmp_path: Path) -> None:
    """--shadow with GPS2 honest for 40 s (5 cm noise: the distance to the receiver is then the twin's own
    error; with a 0.5 m receiver it is the two combined), then gone: `shadow` events at 1 Hz of autopilot time
    only while it is honest, whose gnss_err_m (the twin against the receiver) tells the twin's true error
    (against the simulator's truth) to within 0.3 m in the median; the twin takes the same camera fixes; the
    fused output, which the twin never touches, keeps the no-shadow run's accuracy after the receiver goes."""
    seq, daemon, sim = _live(world, tmp_path, deny_after_s=40.0, gnss_noise_m=0.05, seed=3, shadow=True)
    shadows = [e for e in _events(tmp_path) if e["event"] == "shadow"]
    t_rel = np.array([e["t"] for e in shadows]) - sim.play_start
    assert 30 <= len(shadows) <= 42 and t_rel.max() <= 41.5
    assert np.all(np.diff(t_rel) >= 0.95)  # 1 Hz of autopilot time
    d = sim.drive
    lat = np.interp(t_rel, d.t, d.true_lat)  # sample i plays at play_start + t[i]
    lon = np.interp(t_rel, d.t, d.true_lon)
    true_err = np.array([_metres(a, b, e["lat"], e["lon"]) for a, b, e in zip(lat, lon, shadows)])
    told = np.array([e["gnss_err_m"] for e in shadows])
    assert abs(float(np.median(told)) - float(np.median(true_err))) <= 0.3, (np.median(told), np.median(true_err))
    assert float(np.median(true_err)) > 0.0 and all(e["h_acc_m"] > 0 for e in shadows)
    s = daemon.summary()
    assert s["shadow"]["reports"] == len(shadows)
    assert s["fixes"].get("shadow_accepted", 0) >= 0.8 * s["fixes"].get("accepted", 0) > 0
    # the survey: the twin's camera fixes compared with the receiver while it was there (the first 40 s)
    drive = s["shadow"]["survey"]["drive"]
    assert drive["verdict"] == "usable" and drive["answers"] >= 5 and drive["precision"] >= 0.95, drive
    assert drive["median_error_m"] <= 1.0 and drive["accepted"] <= s["fixes"]["shadow_accepted"]
    assert [st["start_m"] for st in s["shadow"]["survey"]["stretches"]][:2] == [0.0, 200.0]
    _assert_rate(seq)
    assert seq["ate_denied_m"] <= 1.0


def _metres(lat0: float, lon0: float, lat1: float, lon1: float) -> float:
    """Flat-earth distance between two nearby points, m."""
    n = (lat1 - lat0) * 111_320.0
    e = (lon1 - lon0) * 111_320.0 * math.cos(math.radians(lat0))
    return math.hypot(n, e)


def test_autopilot_position_far_from_the_origin_is_no_start() -> None:
    """PX4 sends GLOBAL_POSITION_INT thousands of km from its EKF origin before EKF2 has a global position (seen
    on SIH: 5339 km): refused (counted), the start keeps waiting; a plausible one, moving, then places the start.
    The handlers are a never-started daemon's, given pymavlink-encoded messages."""
    clock = SimClock(boot_offset_s=100.0)
    clock.hold()  # reads 100.0 s throughout
    daemon = Daemon(load_profile("ardupilot_rover"), DaemonOptions(connect="udpin:127.0.0.1:0"), clock=clock)
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    lat, lon = 47.397743, 8.545594
    daemon.origins.on_origin_message(mav.gps_global_origin_encode(int(lat * 1e7), int(lon * 1e7), 488_900, 0), 0.0)
    assert daemon.origin is not None and daemon.anchor.holding(clock())
    daemon.origins.on_position(mav.global_position_int_encode(6000, 2_000_000, -40_000_000, 0, 0, 0, 0, 0, 0), 0.0)
    assert daemon.decoders.rejected["GLOBAL_POSITION_INT:far_from_origin"] == 1
    assert daemon.anchor.holding(clock()) and daemon.anchor.start_source is None
    north = lat + 40.0 / 111_320.0  # 40 m north, driving north at 3 m/s
    daemon.origins.on_position(mav.global_position_int_encode(6200, int(north * 1e7), int(lon * 1e7), 488_900, 0,
                                                              300, 0, 0, 0), 0.0)
    a = daemon.anchor
    assert not a.holding(clock()) and a.start_source == "autopilot"
    assert a.start_xy[1] == pytest.approx(40.0, abs=0.5) and abs(a.start_xy[0]) < 0.5
    assert a.start_speed == pytest.approx(3.0) and a.start_sigma == 3.0 and a.start_t == pytest.approx(6.2)
