"""The daemon's wheel encoders (daemon/wheels.py): WHEEL_DISTANCE from real pymavlink bytes into taco+, and a source
that goes quiet, jumps or gets stuck told once as an event in events.jsonl and a STATUSTEXT."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest
from helpers import simulate, wheel_distances
from pymavlink.dialects.v20 import ardupilotmega as apm
from test_localiser_wheels import POS_Y

from taco_mav.config import Estimator, Profile, localiser_params
from taco_mav.core.wheel_params import WheelParams
from taco_mav.daemon.anchor import LocaliserAnchor
from taco_mav.daemon.eventlog import EventLog
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.state import LiveState
from taco_mav.daemon.wheels import STARTUP_GRACE_S, WheelInput
from taco_mav.core.localiser import make_localiser
from taco_mav.mavlink.decoders import Decoders

PROFILE = Profile(estimator=Estimator.TACO_PLUS, wheels=WheelParams(enabled=True, wheel_pos_y_m=POS_Y))


class FakeLink:
    """What the Reporter sends through: STATUSTEXT texts kept (without the daemon's "TACO: " prefix)."""

    def __init__(self) -> None:
        self.mav = apm.MAVLink(None, srcSystem=1, srcComponent=191)
        self.texts: list[str] = []

    def send(self, msg) -> None:
        self.texts.append(msg.text.removeprefix("TACO: "))


def wheel_msg(t: float, distances) -> object:
    tx = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    d = [float(x) for x in distances] + [0.0] * (16 - len(distances))
    return apm.MAVLink(None).parse_buffer(bytes(tx.wheel_distance_encode(int(round(t * 1e6)), len(distances), d)
                                                .pack(tx)))[0]


@dataclasses.dataclass
class Rig:
    wheels: WheelInput
    state: LiveState
    link: FakeLink
    events_path: Path
    reporter: Reporter
    now: list[float]

    def events(self) -> list[dict]:
        self.reporter.close()
        return [json.loads(line) for line in self.events_path.read_text().splitlines()]


def rig(tmp_path: Path, profile: Profile = PROFILE, pos_y=lambda: None) -> Rig:
    now = [0.0]
    reporter = Reporter(lambda: now[0], 5.0)
    link, path = FakeLink(), tmp_path / "events.jsonl"
    reporter.open(EventLog(path), link)
    state = LiveState(LocaliserAnchor(localiser_params(profile)))
    wheels = WheelInput(profile=profile, state=state, decoders=Decoders(), reporter=reporter, pos_y=pos_y)
    return Rig(wheels, state, link, path, reporter, now)


def test_only_an_enabled_profile_takes_wheel_distance(tmp_path: Path) -> None:
    assert set(rig(tmp_path).wheels.handlers()) == {"WHEEL_DISTANCE"}
    assert rig(tmp_path, Profile()).wheels.handlers() == {}


def test_a_drive_reaches_taco_plus_and_a_stuck_encoder_is_told_once(tmp_path: Path) -> None:
    r = rig(tmp_path)
    d = simulate(lambda t: min(3.0, 0.5 + t), lambda t: 0.0, 30.0, rate_hz=50.0, accel_noise=0.02, seed=2)
    dist = wheel_distances(d, POS_Y)
    r.state.loc = make_localiser(localiser_params(PROFILE), 0.0, heading=float(d.theta[0]), speed=0.5)
    for k, s in enumerate(d.samples):
        r.state.loc.add_imu(s)
        r.state.loc.set_drive_command(s.t, True)
        r.now[0] = s.t
        if k % 2 == 0:  # 25 Hz
            r.wheels.on_wheel_distance(wheel_msg(s.t, dist[min(k, 1000)]), 0.0)  # frozen from 20 s on
    assert r.wheels.counts["used"] > 400 and r.wheels.counts["stuck"] >= 3
    assert r.state.loc.estimate().speed == pytest.approx(3.0, abs=0.3)
    refused = [e for e in r.events() if e["event"] == "wheels_refused"]
    assert [e["reason"] for e in refused] == ["stuck"] and refused[0]["t"] == pytest.approx(20.1, abs=0.1)
    assert r.link.texts.count("wheels refused: stuck") == 1


def test_a_jump_is_refused_with_an_event_and_differencing_starts_again(tmp_path: Path) -> None:
    r = rig(tmp_path)
    r.wheels.on_wheel_distance(wheel_msg(1.0, (0.0, 0.0)), 0.0)
    r.wheels.on_wheel_distance(wheel_msg(1.05, (3.0, 0.05)), 0.0)  # 60 m/s on one wheel
    r.wheels.on_wheel_distance(wheel_msg(1.10, (3.1, 0.15)), 0.0)
    assert r.wheels.counts == {"first": 1, "jump": 1, "no_filter": 1}
    (event,) = [e for e in r.events() if e["event"] == "wheels_refused"]
    assert event["reason"] == "jump" and event["distances"] == [3.0, 0.05]
    assert r.link.texts == ["wheels refused: jump"]


def test_quiet_wheels_are_told_and_their_return_too(tmp_path: Path) -> None:
    r = rig(tmp_path)
    r.wheels.watch(0.0)
    r.wheels.watch(STARTUP_GRACE_S + 0.5)
    assert not r.wheels.quiet  # within the start-up grace
    r.wheels.watch(STARTUP_GRACE_S + 1.5)
    assert r.wheels.quiet  # never heard
    r.now[0] = 20.0
    r.wheels.on_wheel_distance(wheel_msg(5.0, (0.0, 0.0)), 0.0)
    assert not r.wheels.quiet
    r.wheels.watch(20.9)
    r.wheels.watch(21.2)  # 1.2 s > wheels.quiet_s = 1 s
    kinds = [(e["event"], e.get("silent_s"), e.get("heard")) for e in r.events() if e["event"].startswith("wheels")]
    assert kinds == [("wheels_quiet", 11.5, False), ("wheels_back", 20.0, None), ("wheels_quiet", 1.2, True)]
    assert r.link.texts == ["wheels quiet: no WHEEL_DISTANCE", "wheels back", "wheels quiet: no WHEEL_DISTANCE"]


def test_the_wheel_positions_come_from_the_autopilot_when_the_profile_says_so(tmp_path: Path) -> None:
    auto = dataclasses.replace(PROFILE, wheels=dataclasses.replace(PROFILE.wheels, pos_y_from_autopilot=True))
    answered: list[tuple[float, float] | None] = [None]
    r = rig(tmp_path, auto, pos_y=lambda: answered[0])
    r.wheels.on_wheel_distance(wheel_msg(1.0, (0.0, 0.0)), 0.0)
    assert r.wheels.odometry.pos_y == POS_Y and not r.wheels.geometry_known
    answered[0] = (0.2, -0.2)
    r.wheels.on_wheel_distance(wheel_msg(1.1, (0.1, 0.1)), 0.0)
    assert r.wheels.odometry.pos_y == (0.2, -0.2)
    assert [e["pos_y_m"] for e in r.events() if e["event"] == "wheels_geometry"] == [[0.2, -0.2]]
    assert not math.isnan(r.wheels.odometry.pos_y[0])
