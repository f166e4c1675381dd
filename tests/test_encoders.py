"""Output encoders: encode with taco_mav.mavlink.encoders, decode the bytes with pymavlink, check fields and units."""

from __future__ import annotations

import calendar
import dataclasses
import math
import os

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from taco_mav.config import OutputConfig  # noqa: E402
from taco_mav.core.types import Estimate  # noqa: E402
from taco_mav.mavlink import encoders  # noqa: E402

CFG = OutputConfig()
ORIGIN = encoders.Origin.from_latlon(49.0, 8.4, 115.0)


def roundtrip(msg_builder):
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    msg = msg_builder(tx)
    buf = msg.pack(tx)
    rx = mavlink.MAVLink(None)
    out = rx.parse_buffer(bytes(buf))
    assert out is not None and len(out) == 1
    return out[0]


def est(xy=(0.0, 0.0), theta=0.0, speed=0.0, cov=None, t=10.0) -> Estimate:
    cov = np.diag([1.0, 4.0]) if cov is None else cov
    return Estimate(t, np.array(xy, float), theta, speed, np.asarray(cov, float), 0.5)


def test_yaw_cdeg_mapping() -> None:
    assert encoders.yaw_cdeg(0.0) == 36000
    assert encoders.yaw_cdeg(2 * math.pi) == 36000
    assert encoders.yaw_cdeg(math.radians(90.0)) == 9000
    assert encoders.yaw_cdeg(math.radians(-90.0)) == 27000
    assert encoders.yaw_cdeg(math.radians(0.004)) == 36000  # rounds to 0 -> north, never 0
    assert encoders.yaw_cdeg(float("nan")) == 0


def test_hdop_mapping() -> None:
    assert encoders.hdop_from_accuracy(5.0, 2.0, 0.5) == pytest.approx(2.5)
    assert encoders.hdop_from_accuracy(0.1, 2.0, 0.5) == pytest.approx(0.5)
    assert encoders.hdop_from_accuracy(1e6, 2.0, 0.5) == pytest.approx(99.99)
    assert encoders.hdop_from_accuracy(float("inf"), 2.0, 0.5) == pytest.approx(99.99)


def test_gps_input_fields_and_units() -> None:
    # 100 m east, 200 m north of the origin on the grid, heading true north, 3 m/s
    theta_grid = math.pi / 2 + ORIGIN.convergence
    sol = encoders.solution(est((100.0, 200.0), theta_grid, 3.0), ORIGIN, CFG, healthy=True)
    unix = calendar.timegm((2024, 1, 7, 0, 0, 0))  # Sunday 00:00 UTC: GPS week 2296 (16072 days / 7), + 18 s leap
    msg = roundtrip(lambda mav: encoders.gps_input(mav, sol, CFG, unix))
    lat, lon = ORIGIN.projector.to_latlon(ORIGIN.utm[0] + 100.0, ORIGIN.utm[1] + 200.0)
    assert msg.lat == int(round(lat * 1e7)) and msg.lon == int(round(lon * 1e7))
    assert msg.time_week == 2296 and msg.time_week_ms == 18_000
    assert msg.time_usec == unix * 1_000_000
    assert msg.fix_type == 3 and msg.gps_id == 0 and msg.satellites_visible == 10
    assert msg.horiz_accuracy == pytest.approx(2.0)  # sqrt of the largest eigenvalue of diag(1, 4)
    assert msg.hdop == pytest.approx(1.0) and msg.vdop == pytest.approx(1.0)
    assert msg.yaw == 36000
    assert msg.vn == pytest.approx(3.0, abs=1e-5) and msg.ve == pytest.approx(0.0, abs=1e-5) and msg.vd == 0.0
    assert msg.alt == pytest.approx(115.0)
    assert msg.speed_accuracy == pytest.approx(0.3)
    assert msg.ignore_flags == (mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT | mavlink.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY
                                | mavlink.GPS_INPUT_IGNORE_FLAG_VDOP)


def test_speed_accuracy_is_the_filters_own_where_it_has_one() -> None:
    """taco+'s speed 1-sigma (its speed-error state) is reported when it exceeds max(floor, 5 % of the speed):
    on the IMU alone it grows, and the autopilot must not steer by that speed as if it were 0.3 m/s good; the
    paper's filter has none (NaN): the floor and the fraction as before; GPS_INPUT and ODOMETRY agree."""
    def acc(sigma_speed: float, speed: float = 3.0) -> float:
        e = dataclasses.replace(est(speed=speed), sigma_speed=sigma_speed)
        return encoders.solution(e, ORIGIN, CFG, healthy=True).speed_acc

    assert acc(math.nan) == pytest.approx(0.3) and acc(math.nan, speed=10.0) == pytest.approx(0.5)
    assert acc(0.1) == pytest.approx(0.3) and acc(1.4) == pytest.approx(1.4)
    sol = encoders.solution(dataclasses.replace(est(speed=3.0), sigma_speed=1.4), ORIGIN, CFG, healthy=True)
    msg = roundtrip(lambda mav: encoders.gps_input(mav, sol, CFG, 0.0))
    assert msg.speed_accuracy == pytest.approx(1.4)
    assert acc(math.inf) == pytest.approx(0.3)  # never sent as such


def test_gps_input_without_yaw_and_the_synthetic_profiles_send_none() -> None:
    """output.send_yaw false gives GPS_INPUT.yaw 0 ("no yaw"); the synthetic profiles, scored by the simulator
    rather than steering an autopilot, send none; the rover profiles do."""
    from taco_mav.config import load_profile

    sol = encoders.solution(est(theta=0.3, speed=2.0), ORIGIN, CFG, healthy=True)
    assert roundtrip(lambda mav: encoders.gps_input(mav, sol, OutputConfig(send_yaw=False), 1.7e9)).yaw == 0
    assert roundtrip(lambda mav: encoders.gps_input(mav, sol, CFG, 1.7e9)).yaw != 0
    assert not load_profile("synthetic").output.send_yaw and not load_profile("synthetic_3d").output.send_yaw
    assert load_profile("ardupilot_rover").output.send_yaw


def test_gps_input_heading_east_uses_convergence() -> None:
    # a grid heading of exactly east is true east minus the convergence (about -0.46 deg at 8.4 E: west of 9 E)
    sol = encoders.solution(est(theta=0.0, speed=2.0), ORIGIN, CFG, healthy=True)
    msg = roundtrip(lambda mav: encoders.gps_input(mav, sol, CFG, 1.7e9))
    expect = math.degrees(math.pi / 2 + ORIGIN.convergence)
    assert ORIGIN.convergence < 0
    assert msg.yaw == int(round(expect * 100))
    assert math.degrees(math.atan2(msg.ve, msg.vn)) == pytest.approx(expect, abs=1e-3)


def test_gps_input_never_nan() -> None:
    bad = Estimate(5.0, np.array([float("nan"), 1.0]), float("nan"), float("inf"), np.full((2, 2), np.nan), 0.0)
    sol = encoders.solution(bad, ORIGIN, CFG, healthy=True)
    msg = roundtrip(lambda mav: encoders.gps_input(mav, sol, CFG, 1.7e9))
    values = [msg.alt, msg.hdop, msg.vdop, msg.vn, msg.ve, msg.vd, msg.speed_accuracy, msg.horiz_accuracy,
              msg.vert_accuracy]
    assert all(math.isfinite(v) for v in values)
    assert msg.fix_type == 1
    assert msg.lat == int(round(49.0 * 1e7)) and msg.lon == int(round(8.4 * 1e7))
    assert msg.horiz_accuracy == pytest.approx(1000.0)


def test_gps_input_degraded_fix_type() -> None:
    sol = encoders.solution(est(), ORIGIN, CFG, healthy=False)
    msg = roundtrip(lambda mav: encoders.gps_input(mav, sol, CFG, 1.7e9))
    assert msg.fix_type == 1


def test_hil_gps_fields_and_units() -> None:
    """PX4's GNSS path: eph/epv cm, velocity cm/s true north/east (PX4 marks it valid), course cdeg, alt mm."""
    theta_grid = math.pi + ORIGIN.convergence  # heading true west, 2.5 m/s
    sol = encoders.solution(est((10.0, -20.0), theta_grid, 2.5), ORIGIN, CFG, healthy=True)
    msg = roundtrip(lambda mav: encoders.hil_gps(mav, sol, CFG, 1.7e9))
    lat, lon = ORIGIN.latlon(np.array([10.0, -20.0]))
    assert msg.lat == int(round(lat * 1e7)) and msg.lon == int(round(lon * 1e7)) and msg.alt == 115_000
    assert msg.time_usec == 1_700_000_000_000_000 and msg.fix_type == 3 and msg.satellites_visible == 10
    assert msg.eph == 200 and msg.epv == int(CFG.vertical_accuracy_m * 100)
    assert msg.vel == 250 and msg.vn == 0 and msg.ve == -250 and msg.vd == 0
    assert msg.cog == 27000 and msg.yaw == 27000 and msg.id == CFG.gps_id


def test_hil_gps_at_rest_degraded_and_never_nan() -> None:
    still = roundtrip(lambda mav: encoders.hil_gps(mav, encoders.solution(est(), ORIGIN, CFG, healthy=False), CFG, 0.0))
    assert still.cog == 65535 and still.vel == 0 and still.fix_type == 1 and still.time_usec == 0
    bad = Estimate(5.0, np.array([float("nan"), 1.0]), float("nan"), float("inf"), np.full((2, 2), np.nan), 0.0)
    msg = roundtrip(lambda mav: encoders.hil_gps(mav, encoders.solution(bad, ORIGIN, CFG, healthy=True), CFG, 1.7e9))
    assert msg.fix_type == 1 and msg.eph == 65534 and msg.vel == 0  # 1 km accuracy, clipped below "unknown"
    assert msg.lat == int(round(49.0 * 1e7)) and msg.lon == int(round(8.4 * 1e7))


def test_odometry_local_ned_and_covariance() -> None:
    cov = np.array([[1.0, 0.5], [0.5, 4.0]])  # ENU: var_e 1, var_n 4, cov 0.5
    sol = encoders.solution(est((10.0, 20.0), math.pi / 2 + ORIGIN.convergence, 2.0, cov, t=3.0), ORIGIN, CFG, True)
    msg = roundtrip(lambda mav: encoders.odometry(mav, sol, CFG, 0.0, 0.0, (0.0, 0.0, 0.1), 0.05, 2))
    assert msg.x == pytest.approx(20.0) and msg.y == pytest.approx(10.0) and msg.z == 0.0  # north, east
    assert msg.frame_id == mavlink.MAV_FRAME_LOCAL_NED and msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD
    assert msg.pose_covariance[0] == pytest.approx(4.0) and msg.pose_covariance[6] == pytest.approx(1.0)
    assert msg.pose_covariance[1] == pytest.approx(0.5) and msg.pose_covariance[20] == pytest.approx(0.0025)
    assert msg.q[0] == pytest.approx(1.0, abs=1e-6)  # true north, level: identity
    assert msg.vx == pytest.approx(2.0) and msg.yawspeed == pytest.approx(0.1)
    assert msg.reset_counter == 2 and msg.time_usec == 3_000_000 and 0 < msg.quality <= 100


def test_statustext_truncated() -> None:
    msg = roundtrip(lambda mav: encoders.statustext(mav, 4, "x" * 80))
    assert msg.severity == 4 and msg.text == "TACO: " + "x" * 44


@pytest.mark.parametrize("heading_deg", [0.0, 90.0, 210.0])
def test_outputs_carry_the_antenna_point(heading_deg: float) -> None:
    """output.antenna_frd_m: GPS_INPUT, HIL_GPS and ODOMETRY all report the antenna point, the
    estimate (the reference point) plus the antenna's body offset rotated by the heading; altitude - z."""
    ant = OutputConfig(antenna_frd_m=(0.6, 0.3, -0.5))  # 0.6 m ahead, 0.3 m right, 0.5 m above
    th = math.radians(heading_deg)
    e = est((100.0, 200.0), th, 3.0)
    c, s = math.cos(th), math.sin(th)
    east, north = 100.0 + 0.6 * c + 0.3 * s, 200.0 + 0.6 * s - 0.3 * c  # (forward, left) = (0.6, -0.3)
    lat, lon = ORIGIN.projector.to_latlon(ORIGIN.utm[0] + east, ORIGIN.utm[1] + north)
    sol = encoders.solution(e, ORIGIN, ant, healthy=True)
    gps = roundtrip(lambda mav: encoders.gps_input(mav, sol, ant, 1.7e9))
    assert gps.lat == int(round(lat * 1e7)) and gps.lon == int(round(lon * 1e7))
    assert gps.alt == pytest.approx(115.5)
    gps_ref = roundtrip(lambda mav: encoders.gps_input(mav, encoders.solution(e, ORIGIN, CFG, True), CFG, 1.7e9))
    moved = ORIGIN.projector.to_utm(gps.lat * 1e-7, gps.lon * 1e-7)
    ref = ORIGIN.projector.to_utm(gps_ref.lat * 1e-7, gps_ref.lon * 1e-7)
    assert math.dist(moved, ref) == pytest.approx(math.hypot(0.6, 0.3), abs=0.02)  # degE7 ~ 1 cm
    hil = roundtrip(lambda mav: encoders.hil_gps(mav, sol, ant, 1.7e9))
    assert (hil.lat, hil.lon) == (gps.lat, gps.lon) and hil.alt == 115_500
    odo = roundtrip(lambda mav: encoders.odometry(mav, sol, ant, 0.0, 0.0, (0.0, 0.0, 0.0), 0.05, 0))
    assert (odo.x, odo.y) == pytest.approx((north, east), abs=1e-3)
    # a non-finite estimate is still the origin, unmoved
    bad = encoders.solution(est((float("nan"), 0.0), th), ORIGIN, ant, healthy=True)
    assert (bad.x_n, bad.y_e) == (0.0, 0.0) and bad.fix_type == encoders.GPS_FIX_NONE
