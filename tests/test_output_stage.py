"""The output stage: estimates -> GPS_INPUT / HIL_GPS / ODOMETRY bytes (decoded with pymavlink),
with the IMU-stall growth of the accuracy and the health transitions."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from taco_mav.config import load_profile, replace_in  # noqa: E402
from taco_mav.core.types import Estimate  # noqa: E402
from taco_mav.daemon.output_stage import OutputStage  # noqa: E402
from taco_mav.errors import ConfigError  # noqa: E402
from taco_mav.mavlink import encoders  # noqa: E402
from taco_mav.mavlink.decoders import AttitudeReading  # noqa: E402

ORIGIN = encoders.Origin.from_latlon(49.0, 8.4, 115.0)
UTC = 1.7e9


def _decode(msgs: list, tx: mavlink.MAVLink) -> list:
    rx = mavlink.MAVLink(None)
    return [rx.parse_buffer(bytes(m.pack(tx)))[0] for m in msgs]


def _est(sigma: float = 1.0, speed: float = 4.0, xy: tuple[float, float] = (30.0, 40.0)) -> Estimate:
    return Estimate(12.0, np.array(xy), 0.3, speed, np.eye(2) * sigma**2, 0.5)


def _stage(messages: tuple[str, ...]) -> tuple[OutputStage, list[tuple[str, bool]]]:
    changes: list[tuple[str, bool]] = []
    profile = replace_in(load_profile("ardupilot_rover"), "output.messages", messages)
    return OutputStage(profile, lambda text, healthy: changes.append((text, healthy))), changes


def test_unknown_output_name_is_a_config_error() -> None:
    profile = replace_in(load_profile("ardupilot_rover"), "output.messages", ("gps_input", "nmea"))
    with pytest.raises(ConfigError, match=r"output\.messages: \['nmea'\]"):
        OutputStage(profile, lambda *_: None)


def test_gps_input_position_accuracy_and_stall_growth() -> None:
    stage, changes = _stage(("gps_input",))
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    (fresh,) = _decode(stage.messages(_est(), 0.05, ORIGIN, tx, UTC, 0.0, None, (0.0, 0.0, 0.0), 0), tx)
    lat, lon = ORIGIN.latlon(np.array([30.0, 40.0]))
    assert fresh.get_type() == "GPS_INPUT" and fresh.fix_type == 3
    assert fresh.lat == round(lat * 1e7) and fresh.lon == round(lon * 1e7)
    assert fresh.horiz_accuracy == pytest.approx(1.0, abs=0.01)
    assert changes == []
    # 2 s without IMU at 4 m/s: sigma = hypot(1, 0.5 * (4 + 1) * 2) = 5.10 m and no 3D fix
    (stalled,) = _decode(stage.messages(_est(), 2.0, ORIGIN, tx, UTC, 0.0, None, (0.0, 0.0, 0.0), 0), tx)
    assert stalled.fix_type == 1 and stalled.horiz_accuracy == pytest.approx(math.hypot(1.0, 5.0), abs=0.01)
    assert changes == [("degraded: IMU stalled 2.0s", False)]
    (back,) = _decode(stage.messages(_est(), 0.05, ORIGIN, tx, UTC, 0.0, None, (0.0, 0.0, 0.0), 0), tx)
    assert back.fix_type == 3 and changes[-1] == ("recovered: sigma 1.0m", True)


def test_accuracy_hysteresis_and_non_finite_estimate() -> None:
    stage, changes = _stage(("gps_input",))
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    fix = [_decode(stage.messages(_est(sigma=s), 0.0, ORIGIN, tx, UTC, 0.0, None, (0.0, 0.0, 0.0), 0),
                   tx)[0].fix_type for s in (9.0, 11.0, 9.0, 7.5)]
    assert fix == [3, 1, 1, 3]  # degrade above 10 m, recover only under 8 m
    bad = Estimate(12.0, np.array([np.nan, 0.0]), 0.3, 4.0, np.eye(2), 0.5)
    (msg,) = _decode(stage.messages(bad, 0.0, ORIGIN, tx, UTC, 0.0, None, (0.0, 0.0, 0.0), 0), tx)
    assert msg.fix_type == 1 and msg.lat == round(ORIGIN.lat * 1e7) and msg.horiz_accuracy == pytest.approx(1000.0)
    assert changes[-1] == ("degraded: estimate not finite", False)


def test_px4_messages_carry_the_companion_clock_and_attitude() -> None:
    """HIL_GPS (UTC) and ODOMETRY, stamped on the companion clock (autopilot time - offset), as PX4 maps it."""
    stage, _ = _stage(("hil_gps", "odometry"))
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    att = AttitudeReading(t=12.0, roll=0.02, pitch=-0.01, yaw=1.0)
    gps, odo = _decode(stage.messages(_est(), 0.0, ORIGIN, tx, UTC, 100.0, att, (0.0, 0.0, 0.1), 3), tx)
    assert gps.get_type() == "HIL_GPS" and gps.time_usec == int(UTC * 1e6) and gps.fix_type == 3
    assert odo.get_type() == "ODOMETRY" and odo.reset_counter == 3
    assert odo.time_usec == 0  # the estimate (autopilot 12 s) was before the companion clock's zero: clipped
    (late,) = _decode(stage.messages(_est(), 0.0, ORIGIN, tx, UTC, -88.0, att, (0.0, 0.0, 0.1), 3)[1:], tx)
    assert late.time_usec == 100_000_000  # autopilot 12 s = companion 100 s
    assert (odo.x, odo.y) == pytest.approx((40.0, 30.0), abs=1e-3)  # NED: north 40 m, east 30 m
    assert odo.yawspeed == pytest.approx(0.1, abs=1e-6) and odo.vx == pytest.approx(4.0)
