"""The daemon's autopilot handler (daemon/autopilot.py): with the profile's wheels it asks for WHEEL_DISTANCE at
their rate and, when told to, reads the wheels' positions (WENC_POS_Y, WENC2_POS_Y) from the autopilot."""

from __future__ import annotations

import dataclasses

from pymavlink.dialects.v20 import ardupilotmega as apm

from taco_mav.config import load_profile
from taco_mav.daemon.autopilot import AutopilotLink
from taco_mav.daemon.reporter import Reporter
from taco_mav.mavlink.mavconst import MAV_AUTOPILOT_INVALID
from taco_mav.mavlink.timesync import ClockMap


class FakeLink:
    def __init__(self) -> None:
        self.mav = apm.MAVLink(None, srcSystem=1, srcComponent=191)
        self.sent: list = []
        self.target_system, self.target_component = 1, 1

    def send(self, msg) -> None:
        self.sent.append(msg)

    def heartbeat(self) -> None:
        self.sent.append(self.mav.heartbeat_encode(18, 8, 0, 0, 0))


def _link(profile) -> tuple[AutopilotLink, FakeLink]:
    ap = AutopilotLink(profile=profile, clockmap=ClockMap(lambda: 0.0), reporter=Reporter(lambda: 0.0, 5.0),
                       link_timeout_s=3.0, wants_pose=lambda: False)
    link = FakeLink()
    ap.open(link, 0.0)
    ap._request_streams(MAV_AUTOPILOT_INVALID + 3)  # ArduPilot (MAV_AUTOPILOT_ARDUPILOTMEGA)
    return ap, link


def _param(name: str, value: float):
    tx = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    return apm.MAVLink(None).parse_buffer(bytes(tx.param_value_encode(name.encode(), value, 9, 900, 1).pack(tx)))[0]


def test_the_wheels_profile_asks_for_wheel_distance_and_reads_the_wheel_positions() -> None:
    ap, link = _link(load_profile("ardupilot_rover_wheels"))
    assert ap.requester.rates["WHEEL_DISTANCE"] == 20.0
    assert next(iter(ap.requester.rates)) == "WHEEL_DISTANCE"  # first: its fallback sets its group's rate (EXTRA1)
    for now in range(0, 40):  # the stream requests go one at a time; the parameter reads beside them
        ap.tick(float(now) * 0.5)
    asked = {m.param_id for m in link.sent if m.get_type() == "PARAM_REQUEST_READ"}
    assert {"WENC_POS_Y", "WENC2_POS_Y"} <= asked
    assert ap.wheel_pos_y() is None
    ap._on_param_value(_param("WENC_POS_Y", 0.15), 0.0)
    ap._on_param_value(_param("WENC2_POS_Y", -0.15), 0.0)
    assert ap.wheel_pos_y() == (0.15000000596046448, -0.15000000596046448)


def test_a_profile_without_wheels_asks_for_none_of_it() -> None:
    p = load_profile("ardupilot_rover")
    ap, _ = _link(p)
    assert "WHEEL_DISTANCE" not in ap.requester.rates and ap.wheel_params is None
    fixed = load_profile("ardupilot_rover_wheels")
    ap2, _ = _link(dataclasses.replace(fixed, wheels=dataclasses.replace(fixed.wheels, pos_y_from_autopilot=False)))
    assert ap2.wheel_params is None and ap2.wheel_pos_y() is None
