"""The simulator's GNSS as ArduPilot reports it (taco_mav/sim/receiver.py and its use in the simulator): the
real receiver's noise, denial and spoofing, the type-14 instance echoing the companion, GPS1/GPS2 assignment,
HOME_POSITION / GPS_GLOBAL_ORIGIN, and `ate_denied_m`."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as apm

from taco_mav.errors import ConfigError
from taco_mav.geo import UtmProjector
from taco_mav.sim import Simulator
from taco_mav.sim.gps_mav import GpsInputMonitor
from taco_mav.sim.receiver import NO_FIX, EchoInstance, GnssReceiver, gps_message
from taco_mav.sim.score import score_updates
from tests.sim_helpers import EchoCompanion, free_udp_port
from tests.test_sim import _gps_input, _line_drive

MAV = apm.MAVLink(None, srcSystem=1, srcComponent=1)


def _parse(msg):
    return apm.MAVLink(None).parse_buffer(bytes(msg.pack(MAV)))[0]


def _offsets(rx: GnssReceiver, d) -> np.ndarray:
    """(east, north) metres of the receiver's positions from the truth."""
    proj = UtmProjector(d.utm_epsg)
    e, n = proj.to_utm(rx.lat, rx.lon)
    et, nt = proj.to_utm(d.true_lat, d.true_lon)
    return np.c_[e - et, n - nt]


def test_receiver_noise_white_plus_wandering_bias() -> None:
    """sigma 1.5 m over 2000 s: per-axis spread ~1.5 m; the slow part (60 s means) carries most of it, and the
    same seed gives the same draws."""
    d = _line_drive(n=20001, rate=10.0)
    rx = GnssReceiver(d, noise_m=1.5, seed=4)
    off = _offsets(rx, d)
    assert off.std(axis=0) == pytest.approx([1.5, 1.5], rel=0.3)
    slow = off[:19800].reshape(-1, 600, 2).mean(axis=1)  # 60 s means: the white part averages out
    assert slow.std() > 0.6 and (off[:19800] - np.repeat(slow, 600, axis=0)).std() < 1.2
    assert np.array_equal(GnssReceiver(d, noise_m=1.5, seed=4).lat, rx.lat)
    assert not np.array_equal(GnssReceiver(d, noise_m=1.5, seed=5).lat, rx.lat)
    s = rx.state(0)
    assert s.fix_type == 3 and s.h_acc == 1.5 and s.ve == pytest.approx(10.0)


def test_receiver_denial() -> None:
    d = _line_drive()
    never = GnssReceiver(d, deny_after_s=0.0)
    assert all(never.state(i) is NO_FIX for i in (0, 50, 200))
    rx = GnssReceiver(d, deny_after_s=5.0)
    assert rx.state(49).fix_type == 3 and rx.state(50) is NO_FIX  # 10 Hz: sample 50 is t = 5.0 s


def test_receiver_spoofing_keeps_a_confident_fix() -> None:
    """From 10 s: a 20 m jump then 0.5 m/s northward; still 3D with the same accuracy; velocity carries the drag."""
    d = _line_drive(n=301)
    rx = GnssReceiver(d, noise_m=0.0, spoof_after_s=10.0, spoof_drift_mps=0.5, spoof_jump_m=20.0,
                      spoof_bearing_deg=0.0)
    off = _offsets(rx, d)
    assert off[99] == pytest.approx([0.0, 0.0], abs=0.01)
    assert off[100] == pytest.approx([0.0, 20.0], abs=0.01) and off[300] == pytest.approx([0.0, 30.0], abs=0.01)
    s = rx.state(300)
    assert s.fix_type == 3 and s.h_acc == 0.5 and s.vn == pytest.approx(0.5) and s.ve == pytest.approx(10.0)


def test_echo_instance_and_wire_encoding() -> None:
    """The type-14 instance: NO_FIX (no position, unknown velocity) before any GPS_INPUT, then the last one."""
    echo = EchoInstance()
    raw = _parse(gps_message(MAV, 1, 12.5, echo.state()))
    assert raw.get_type() == "GPS_RAW_INT" and raw.fix_type == 1 and (raw.lat, raw.lon) == (0, 0)
    assert raw.vel == 65535 and raw.time_usec == 12_500_000
    echo.on_gps_input(_gps_input(lat=49.01, lon=8.41, hacc=1.7))
    two = _parse(gps_message(MAV, 2, 13.0, echo.state()))
    assert two.get_type() == "GPS2_RAW" and two.fix_type == 3 and two.lat == 490_100_000 and two.lon == 84_100_000
    assert two.h_acc == 1700 and two.eph == 80 and two.satellites_visible == 10 and two.alt == 100_000


def test_gps_types_and_options() -> None:
    d = _line_drive()
    assert Simulator(d, "udpout:127.0.0.1:9").options.gps_types == (14, 1)
    sim = Simulator(d, "udpout:127.0.0.1:9", gps1_type=1)
    assert sim.options.gps_types == (1, 14) and sim.monitor.instance == 1
    assert Simulator(d, "udpout:127.0.0.1:9", gps1_type=1, gps2_type=0).monitor.instance == -1
    assert sim.home == (pytest.approx(d.true_lat[0]), pytest.approx(d.true_lon[0]), 110.0)
    for bad in (dict(gnss_noise_m=-1.0), dict(spoof_after_s=-1.0), dict(gps2_type=99), dict(home=(95.0, 0.0, 0.0))):
        with pytest.raises(ConfigError):
            Simulator(d, "udpout:127.0.0.1:9", **bad)
    assert Simulator(d, "udpout:127.0.0.1:9", deny_after_s=5.0, spoof_after_s=3.0).denied_from_s == 3.0
    assert Simulator(d, "udpout:127.0.0.1:9", deny_after_s=math.inf).denied_from_s is None


def test_ate_denied_over_the_denied_span() -> None:
    """3 m off only after 10 s: ate_m mixes both spans, ate_denied_m is the later one's."""
    d = _line_drive()
    proj = UtmProjector(32632)
    mon = GpsInputMonitor()
    for k in range(0, 201, 2):
        e, n = d.origin_utm + d.truth.xy[k] + [0.0, 3.0 if d.t[k] >= 10.0 else 0.0]
        lat, lon = proj.to_latlon(e, n)
        mon.handle(_gps_input(lat=lat, lon=lon), 100.0 + d.t[k])
    s = score_updates(d, mon.updates, 100.0, denied_from_s=10.0)
    assert s["ate_denied_m"] == pytest.approx(3.0, abs=0.02) and s["max_error_denied_m"] == pytest.approx(3.0, abs=0.02)
    assert s["ate_m"] == pytest.approx(3.0 * math.sqrt(51 / 101), abs=0.05) and s["denied_updates"] == 51
    assert "ate_denied_m" not in score_updates(d, mon.updates, 100.0)


def test_live_gps1_real_companion_gps2() -> None:
    """--gps1-type 1 over real UDP: GPS1 (GPS_RAW_INT) is the receiver (3D for 1 s, then NO_FIX), GPS2 (GPS2_RAW)
    echoes the companion's GPS_INPUT with gps_id 1, which the driver keeps; GPS1_TYPE / GPS2_TYPE answered;
    HOME_POSITION and GPS_GLOBAL_ORIGIN are the drive's start, also on MAV_CMD_REQUEST_MESSAGE."""
    d = _line_drive(n=101)
    port = free_udp_port()
    sim = Simulator(d, f"udpout:127.0.0.1:{port}", speed=10.0, lockstep=True, wait_companion_s=5.0, drain_s=0.3,
                    gps1_type=1, gnss_noise_m=0.0)
    comp = EchoCompanion(port, sim.clock, gps_id=1, h_acc=1.3).start()
    try:
        sim.start()
        deadline = time.monotonic() + 5.0
        while len(comp.received.get("GPS_RAW_INT", ())) < 3 and time.monotonic() < deadline:  # playing
            time.sleep(0.005)
        comp.conn.mav.param_request_read_send(1, 1, b"GPS2_TYPE", -1)
        comp.conn.mav.command_long_send(1, 1, 512, 0, apm.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 0, 0, 0, 0, 0, 0)
        assert sim.join(timeout=30.0)
    finally:
        comp.close()
    got = comp.received
    assert sorted((m.param_id, m.param_value) for m in got["PARAM_VALUE"]) == [("GPS1_TYPE", 1.0), ("GPS2_TYPE", 14.0)]
    gps1, gps2 = got["GPS_RAW_INT"], got["GPS2_RAW"]
    t0 = gps1[0].time_usec
    assert {m.fix_type for m in gps1 if m.time_usec - t0 < 1_000_000} == {3}
    assert {m.fix_type for m in gps1 if m.time_usec - t0 >= 1_000_000} == {1}
    assert gps1[0].lat == round(d.true_lat[0] * 1e7) and gps1[0].h_acc == 500
    assert gps2[0].fix_type == 1 and gps2[-1].fix_type == 3 and gps2[-1].h_acc == 1300
    seq = sim.results()["sequences"]["line"]
    assert seq["gps_input_dropped_wrong_id"] == 0 and seq["gps_input_count"] >= 45 and seq["ate_m"] < 1.5
    assert seq["ate_denied_m"] is not None and seq["denied_from_s"] == 1.0
    assert (512, 0) in sim.services.ack_log
    assert len(got["GPS_GLOBAL_ORIGIN"]) >= len(got["HOME_POSITION"]) + 1  # 1 Hz each, plus the one requested
    assert got["HOME_POSITION"][0].latitude == round(d.true_lat[0] * 1e7)


def test_cli_sim_gnss_arguments(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """`taco-mav sim` passes the GNSS arguments through to `simulate`."""
    import taco_mav.sim as sim_pkg
    from taco_mav.cli import main

    seen = {}

    def fake(drive, connect, out, speed, **kw):
        seen.update(kw)
        return {"sequences": {}}

    monkeypatch.setattr(sim_pkg, "simulate", fake)
    rc = main(["sim", "-q", "--drive", str(tmp_path), "--connect", "udpout:127.0.0.1:9", "--out", str(tmp_path),
               "--gps1-type", "1", "--gnss-noise", "1.5", "--seed", "3", "--spoof-after", "60", "--spoof-drift", "0.5",
               "--spoof-jump", "10", "--home", "49.0,8.4,115", "--deny-after", "0"])
    assert rc == 0
    assert seen["gps1_type"] == 1 and seen["gps2_type"] is None and seen["gnss_noise_m"] == 1.5 and seen["seed"] == 3
    assert (seen["spoof_after_s"], seen["spoof_drift_mps"], seen["spoof_jump_m"]) == (60.0, 0.5, 10.0)
    assert seen["home"] == (49.0, 8.4, 115.0) and seen["send_home"] and seen["deny_after_s"] == 0.0
    assert main(["sim", "-q", "--drive", "x", "--connect", "udpout:127.0.0.1:9", "--out", str(tmp_path),
                 "--home", "49.0"]) == 2  # a usage error: exit 2
