"""Input decoders: scaling (mG, mrad/s, degE7, cm/s, cdeg), FRD frames, validation and rejection counts.
Messages are encoded and parsed by pymavlink so the field types are the wire's."""

from __future__ import annotations

import math
import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from taco_mav.mavlink.decoders import G0, MAX_ATTITUDE_CARRY_S, Decoders, euler_rates  # noqa: E402


def wire(build):
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    return mavlink.MAVLink(None).parse_buffer(bytes(build(tx).pack(tx)))[0]


def test_raw_imu_level_at_rest() -> None:
    d = Decoders()
    r = d.imu(wire(lambda m: m.raw_imu_encode(12_345_678, 10, -20, -1000, 100, -200, 300, 0, 0, 0)))
    assert r.t == pytest.approx(12.345678)
    assert r.accel_frd == pytest.approx((10 * G0 / 1000, -20 * G0 / 1000, -9.80665))
    assert r.gyro_frd == pytest.approx((0.1, -0.2, 0.3))
    assert r.source == "RAW_IMU"


@pytest.mark.parametrize("kind", ["scaled_imu", "scaled_imu2", "scaled_imu3"])
def test_scaled_imu_time_boot_ms(kind: str) -> None:
    d = Decoders()
    r = d.imu(wire(lambda m: getattr(m, f"{kind}_encode")(4_500, 0, 0, -1000, 0, 0, -50, 0, 0, 0)))
    assert r.t == pytest.approx(4.5) and r.accel_frd[2] == pytest.approx(-G0) and r.gyro_frd[2] == pytest.approx(-0.05)


def test_highres_imu_si() -> None:
    d = Decoders()
    r = d.imu(wire(lambda m: m.highres_imu_encode(2_000_000, 0.5, 0.0, -9.8, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 0,
                                                  0x3F)))
    assert r.t == pytest.approx(2.0) and r.accel_frd == pytest.approx((0.5, 0.0, -9.8))
    assert r.gyro_frd == pytest.approx((0.01, 0.02, 0.03))
    partial = d.imu(wire(lambda m: m.highres_imu_encode(2_000_000, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x07)))
    assert partial is None and d.rejected["HIGHRES_IMU:partial"] == 1


def test_imu_rejections_counted() -> None:
    d = Decoders()
    assert d.imu(wire(lambda m: m.highres_imu_encode(1_000_000, float("nan"), 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))) is None
    assert d.imu(wire(lambda m: m.raw_imu_encode(1_000, 0, 0, -20000, 0, 0, 0, 0, 0, 0))) is None  # 20 g
    assert d.imu(wire(lambda m: m.highres_imu_encode(1_000, 0, 0, -9.8, 0, 0, 40.0, 0, 0, 0, 0, 0, 0, 0, 0))) is None
    assert d.imu(wire(lambda m: m.raw_imu_encode(0, 0, 0, -1000, 0, 0, 0, 0, 0, 0))) is None
    assert d.imu(wire(lambda m: m.raw_imu_encode(1_000, 0, 0, 0, 0, 0, 0, 0, 0, 0))) is None
    assert dict(d.rejected) == {"HIGHRES_IMU:nonfinite": 1, "RAW_IMU:accel_range": 1, "HIGHRES_IMU:gyro_range": 1,
                                "RAW_IMU:no_time": 1, "RAW_IMU:all_zero": 1}


def test_attitude_ned() -> None:
    d = Decoders()
    a = d.attitude(wire(lambda m: m.attitude_encode(1500, 0.1, -0.2, 3.5, 0, 0, 0)))
    assert a.t == pytest.approx(1.5) and a.roll == pytest.approx(0.1) and a.pitch == pytest.approx(-0.2)
    assert a.yaw == pytest.approx(3.5 - 2 * math.pi)  # wrapped to [-pi, pi]
    assert d.attitude(wire(lambda m: m.attitude_encode(1500, float("nan"), 0, 0, 0, 0, 0))) is None
    assert d.attitude(wire(lambda m: m.attitude_encode(1500, 0, 2.0, 0, 0, 0, 0))) is None
    assert dict(d.rejected) == {"ATTITUDE:nonfinite": 1, "ATTITUDE:range": 1}


@pytest.mark.parametrize("seed", range(5))
def test_euler_rates_match_body_rate_integration(seed: int) -> None:
    """ZYX Euler rates from FRD body rates agree with scipy integrating R' = R [w]x over 1 ms."""
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-3.0, 3.0)
    w = rng.uniform(-1.0, 1.0, 3)
    h = 1e-3
    r0 = Rotation.from_euler("ZYX", [yaw, pitch, roll])
    y1, p1, r1 = (r0 * Rotation.from_rotvec(w * h)).as_euler("ZYX")
    numeric = [(r1 - roll) / h, (p1 - pitch) / h, math.remainder(y1 - yaw, 2 * math.pi) / h]
    assert euler_rates(roll, pitch, *w) == pytest.approx(numeric, abs=2e-3)


def test_attitude_carried_to_imu_time() -> None:
    """A level vehicle turning at 0.5 rad/s: the 0.1 s old ATTITUDE is carried to the IMU sample's time
    (0.05 rad more yaw, wrapped through +-pi); beyond MAX_ATTITUDE_CARRY_S it is left as received."""
    d = Decoders()
    a = d.attitude(wire(lambda m: m.attitude_encode(10_000, 0.0, 0.0, 3.12, 0.0, 0.0, 0.5)))
    assert a.euler_rates == pytest.approx((0.0, 0.0, 0.5))
    b = a.at(10.1)
    assert b.t == pytest.approx(10.1) and b.yaw == pytest.approx(3.17 - 2 * math.pi)
    assert a.at(9.95).yaw == pytest.approx(3.095)
    assert a.at(10.0 + MAX_ATTITUDE_CARRY_S + 0.01) == a
    bad = d.attitude(wire(lambda m: m.attitude_encode(10_000, 0.0, 0.0, 1.0, 0.0, float("nan"), 0.5)))
    assert bad is not None and bad.euler_rates == (0.0, 0.0, 0.0) and bad.at(10.1).yaw == pytest.approx(1.0)
    assert d.rejected == {"ATTITUDE:rates": 1}


def test_gps_raw_int_scaling() -> None:
    d = Decoders()
    g = d.gnss(wire(lambda m: m.gps_raw_int_encode(7_000_000, 3, 490_123_456, 84_567_890, 115_250, 80, 120, 523, 9050, 12)))
    assert g.lat == pytest.approx(49.0123456) and g.lon == pytest.approx(8.456789) and g.alt == pytest.approx(115.25)
    assert g.speed == pytest.approx(5.23) and g.course_ned == pytest.approx(math.radians(90.5))
    assert g.t == pytest.approx(7.0) and g.satellites == 12
    unknown = d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 4, 1, 1, 0, 0, 0, 65535, 65535, 9)))
    assert unknown.speed == 0.0 and unknown.course_ned is None
    assert d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 2, 490_000_000, 84_000_000, 0, 0, 0, 0, 0, 5))) is None
    assert d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 3, 0, 0, 0, 0, 0, 0, 0, 5))) is None
    assert dict(d.rejected) == {"GPS_RAW_INT:no_3d_fix": 1, "GPS_RAW_INT:position_range": 1}


def test_simstate_pose() -> None:
    d = Decoders()
    p = d.sim_pose(wire(lambda m: m.simstate_encode(0, 0, 0.5, 0, 0, -9.8, 0, 0, 0, -353632610, 1491652300)))
    assert p.lat == pytest.approx(-35.363261) and p.lon == pytest.approx(149.16523) and p.yaw == pytest.approx(0.5)


def test_hil_state_quaternion_pose() -> None:
    """PX4 SIH's truth: yaw from the body-to-NED quaternion [w, x, y, z]; an unset position is refused."""
    d = Decoders()
    yaw = 2.0
    q = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    p = d.sim_pose(wire(lambda m: m.hil_state_quaternion_encode(0, q, 0, 0, 0, 473977432, 85455942, 488929,
                                                                  0, 0, 0, 0, 0, 0, 0, 0)))
    assert p.lat == pytest.approx(47.3977432) and p.lon == pytest.approx(8.5455942) and p.yaw == pytest.approx(yaw)
    assert d.sim_pose(wire(lambda m: m.hil_state_quaternion_encode(0, q, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
                                                                     0))) is None
    assert dict(d.rejected) == {"HIL_STATE_QUATERNION:range": 1}


def test_positions_outside_utm_band_rejected() -> None:
    """The daemon works on a UTM grid: polar fixes (and SIMSTATE poses) are refused, never projected."""
    d = Decoders()
    assert d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 3, 850_000_000, 84_000_000, 0, 0, 0, 0, 0, 9))) is None
    assert d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 3, -805_000_000, 84_000_000, 0, 0, 0, 0, 0, 9))) is None
    assert d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 3, 839_000_000, 84_000_000, 0, 0, 0, 0, 0, 9))) is not None
    assert d.sim_pose(wire(lambda m: m.simstate_encode(0, 0, 0.5, 0, 0, -9.8, 0, 0, 0, 890_000_000, 1))) is None
    assert dict(d.rejected) == {"GPS_RAW_INT:outside_utm": 2, "SIMSTATE:range": 1}
    d.reject("RAW_IMU", "foreign_source")
    assert d.rejected["RAW_IMU:foreign_source"] == 1


def test_gps2_raw_and_accuracies() -> None:
    """GPS2_RAW is instance 2; h_acc mm -> m, vel_acc mm/s -> m/s, eph = HDOP x 100; 0 / 65535 = not reported."""
    d = Decoders()
    g = d.gnss(wire(lambda m: m.gps2_raw_encode(3_000_000, 4, 490_000_000, 84_000_000, 110_000, 90, 140, 250, 18000,
                                                14, 0, 0, 0, 110_000, 1_250, 2_000, 300, 0)))
    assert g.instance == 2 and g.fix_type == 4 and g.h_acc_m == pytest.approx(1.25) and g.hdop == pytest.approx(0.9)
    assert g.vel_acc_mps == pytest.approx(0.3) and g.course_ned == pytest.approx(math.pi) and g.speed_known
    g1 = d.gnss(wire(lambda m: m.gps_raw_int_encode(1, 3, 490_000_000, 84_000_000, 0, 65535, 0, 65535, 65535, 9)))
    assert g1.instance == 1 and g1.h_acc_m is None and g1.hdop is None and g1.vel_acc_mps is None
    assert not g1.speed_known and g1.speed == 0.0


@pytest.mark.parametrize("kind", ["gps_raw_int", "gps2_raw"])
def test_gnss_absurd_values_rejected(kind: str) -> None:
    """Values no ground receiver reports refuse the reading, counted by reason."""
    d = Decoders()
    name = kind.upper()

    def msg(fix=3, lat=490_000_000, lon=84_000_000, alt=115_000, eph=80, vel=500, cog=9000, h_acc=800):
        if kind == "gps_raw_int":
            return wire(lambda m: m.gps_raw_int_encode(1, fix, lat, lon, alt, eph, 0, vel, cog, 9, 0, h_acc, 0, 0, 0))
        return wire(lambda m: m.gps2_raw_encode(1, fix, lat, lon, alt, eph, 0, vel, cog, 9, 0, 0, 0, 0, h_acc, 0, 0, 0))

    for kwargs in (dict(fix=200), dict(alt=2**31 - 1), dict(vel=65534), dict(cog=40000), dict(h_acc=2**32 - 1),
                   dict(lat=2**31 - 1), dict(fix=0)):
        assert d.gnss(msg(**kwargs)) is None
    assert dict(d.rejected) == {f"{name}:fix_type_range": 1, f"{name}:alt_range": 1, f"{name}:speed_range": 1,
                                f"{name}:course_range": 1, f"{name}:accuracy_range": 1, f"{name}:position_range": 1,
                                f"{name}:no_3d_fix": 1}
    assert d.gnss(msg()) is not None


@pytest.mark.parametrize("seed", range(3))
def test_gnss_fuzz_only_counters(seed: int) -> None:
    """Random field values (every int at its type's extremes or anywhere): each message is either refused and
    counted, or a reading inside the documented ranges."""
    import random

    rnd = random.Random(seed)
    d = Decoders()
    accepted = 0
    for k in range(2000):
        f = dict(fix=rnd.choice([0, 1, 2, 3, 4, 6, 8, 9, 255]), lat=rnd.randint(-2**31, 2**31 - 1),
                 lon=rnd.randint(-2**31, 2**31 - 1), alt=rnd.randint(-2**31, 2**31 - 1), eph=rnd.randint(0, 65535),
                 vel=rnd.randint(0, 65535), cog=rnd.randint(0, 65535), h=rnd.choice([0, rnd.randint(0, 2**32 - 1)]))
        if k % 2:
            m = wire(lambda m: m.gps_raw_int_encode(rnd.randint(0, 2**64 - 1), f["fix"], f["lat"], f["lon"], f["alt"],
                                                    f["eph"], 0, f["vel"], f["cog"], 9, 0, f["h"], 0, 0, 0))
        else:
            m = wire(lambda m: m.gps2_raw_encode(rnd.randint(0, 2**64 - 1), f["fix"], f["lat"], f["lon"], f["alt"],
                                                 f["eph"], 0, f["vel"], f["cog"], 9, 0, 0, 0, 0, f["h"], 0, 0, 0))
        g = d.gnss(m)
        if g is not None:
            accepted += 1
            assert 3 <= g.fix_type <= 8 and -80 <= g.lat <= 84 and abs(g.alt) <= 20_000 and 0 <= g.speed <= 150
            assert g.h_acc_m is None or 0 < g.h_acc_m <= 1000
    assert sum(d.rejected.values()) + accepted == 2000 and accepted < 20


def test_origin_messages() -> None:
    d = Decoders()
    o = d.origin(wire(lambda m: m.gps_global_origin_encode(-353_632_610, 1_491_652_300, 584_070, 0)))
    assert (o.lat, o.lon, o.alt, o.source) == (pytest.approx(-35.363261), pytest.approx(149.16523),
                                               pytest.approx(584.07), "GPS_GLOBAL_ORIGIN")
    h = d.origin(wire(lambda m: m.home_position_encode(490_000_000, 84_000_000, 115_000, float("nan"), 0, 0,
                                                       [float("nan")] * 4, 0, 0, 0)))
    assert h.source == "HOME_POSITION" and h.alt == pytest.approx(115.0)  # NaN local fields are not used
    assert d.origin(wire(lambda m: m.home_position_encode(0, 0, 0, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0))) is None
    assert d.origin(wire(lambda m: m.gps_global_origin_encode(900_000_001, 0, 0))) is None
    assert d.origin(wire(lambda m: m.gps_global_origin_encode(850_000_000, 10, 0))) is None
    assert d.origin(wire(lambda m: m.gps_global_origin_encode(490_000_000, 84_000_000, -2**31))) is None
    assert dict(d.rejected) == {"HOME_POSITION:unset": 1, "GPS_GLOBAL_ORIGIN:position_range": 2,
                                "GPS_GLOBAL_ORIGIN:outside_utm": 1}


def test_wheel_distance_from_real_bytes() -> None:
    d = Decoders()
    r = d.wheel_distance(wire(lambda m: m.wheel_distance_encode(123_456_000, 2, [1.25, -0.5] + [9.0] * 14)))
    assert r.t == pytest.approx(123.456) and r.distances == (1.25, -0.5)  # only `count` wheels


@pytest.mark.parametrize("time_usec,count,first,reason", [
    (1_000_000, 0, 1.0, "count"), (1_000_000, 17, 1.0, "count"), (0, 2, 1.0, "no_time"),
    (1_000_000, 2, math.inf, "range"), (1_000_000, 2, 2.0e7, "range"),
])
def test_wheel_distance_refusals_counted(time_usec: int, count: int, first: float, reason: str) -> None:
    d = Decoders()
    msg = wire(lambda m: m.wheel_distance_encode(time_usec, min(count, 255), [first] + [0.0] * 15))
    assert d.wheel_distance(msg) is None
    assert d.rejected == {f"WHEEL_DISTANCE:{reason}": 1}
