"""Whether the autopilot drives (daemon/drive.py), from real HEARTBEAT messages as ArduPilot and PX4 send them."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from taco_mav.daemon.drive import DRIVE_THROTTLE_MIN_PCT, DriveCommand  # noqa: E402

ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def heartbeat(autopilot: int, base_mode: int, custom_mode: int):
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    buf = tx.heartbeat_encode(mavlink.MAV_TYPE_GROUND_ROVER, autopilot, base_mode, custom_mode,
                              mavlink.MAV_STATE_ACTIVE).pack(tx)
    return mavlink.MAVLink(None).parse_buffer(bytes(buf))[0]


def px4_mode(main: int, sub: int) -> int:
    return (main << 16) | (sub << 24)


def test_unknown_before_the_first_heartbeat() -> None:
    assert DriveCommand().driving(50) is None


@pytest.mark.parametrize("base_mode, throttle, driving", [(ARMED, DRIVE_THROTTLE_MIN_PCT, True), (ARMED, -40, True),
                                                          (ARMED, 0, False), (ARMED, DRIVE_THROTTLE_MIN_PCT - 1, False),
                                                          (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 60, False)])
def test_ardupilot_drives_when_armed_with_throttle(base_mode: int, throttle: int, driving: bool) -> None:
    d = DriveCommand()
    d.on_heartbeat(heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode, 10))  # Rover AUTO
    assert d.driving(throttle) is driving


@pytest.mark.parametrize("mode, armed, driving", [(px4_mode(4, 4), True, True),   # AUTO.MISSION
                                                  (px4_mode(4, 5), True, True),   # AUTO.RTL
                                                  (px4_mode(3, 0), True, True),   # POSCTL
                                                  (px4_mode(4, 3), True, False),  # AUTO.LOITER (Hold)
                                                  (px4_mode(4, 1), True, False),  # AUTO.READY
                                                  (px4_mode(4, 4), False, False)])
def test_px4_drives_when_armed_outside_hold_whatever_its_throttle(mode: int, armed: bool, driving: bool) -> None:
    """PX4's rover never fills VFR_HUD.throttle (0 while it cruises): its mode decides, on the safe side."""
    d = DriveCommand()
    d.on_heartbeat(heartbeat(mavlink.MAV_AUTOPILOT_PX4, ARMED if armed else 0, mode))
    assert d.driving(0) is driving
