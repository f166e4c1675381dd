"""SET_MESSAGE_INTERVAL requests as ArduPilot answers them (mavlink/requests.py): a rate it calls "too fast" is
asked for again slower (ArduPilot Rover SITL refuses 50 Hz and takes 40 Hz), then falls back to a
data stream; real pymavlink messages through a real MAVLink encoder/decoder."""

import os

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as m  # noqa: E402

from taco_mav.mavlink.requests import StreamRequester  # noqa: E402


class _Wire:
    """Our side's encoder; the autopilot's side decodes what we sent and answers COMMAND_ACK bytes."""

    def __init__(self) -> None:
        self.ours = m.MAVLink(None, srcSystem=1, srcComponent=191)
        self.theirs = m.MAVLink(None, srcSystem=1, srcComponent=1)
        self.sent: list = []

    def send(self, msg) -> None:
        buf = msg.pack(self.ours)
        self.sent.append(self.theirs.decode(bytearray(buf)))

    def ack(self, result: int):
        buf = self.theirs.command_ack_encode(m.MAV_CMD_SET_MESSAGE_INTERVAL, result).pack(self.theirs)
        return self.ours.decode(bytearray(buf))


def _intervals(wire: _Wire) -> list[tuple[int, float]]:
    return [(int(c.param1), c.param2) for c in wire.sent if c.get_type() == "COMMAND_LONG"
            and c.command == m.MAV_CMD_SET_MESSAGE_INTERVAL]


def test_a_refused_rate_is_asked_for_slower_and_then_taken():
    wire = _Wire()
    req = StreamRequester(wire.send, wire.ours, {"RAW_IMU": 50.0})
    req.tick(0.0, 1, 1)
    assert _intervals(wire) == [(m.MAVLINK_MSG_ID_RAW_IMU, 20000.0)]
    req.on_message(wire.ack(m.MAV_RESULT_DENIED), 1, 1)
    req.tick(0.1, 1, 1)  # asked again at once, 0.8 x the rate
    assert _intervals(wire)[-1] == (m.MAVLINK_MSG_ID_RAW_IMU, 25000.0)
    req.on_message(wire.ack(m.MAV_RESULT_ACCEPTED), 1, 1)
    assert req.done and not req.fallback_streams
    assert req._reqs[m.MAVLINK_MSG_ID_RAW_IMU].rate_hz == 40.0


def test_refused_at_every_rate_falls_back_to_the_data_stream():
    wire = _Wire()
    req = StreamRequester(wire.send, wire.ours, {"ATTITUDE": 50.0})
    now = 0.0
    for _ in range(3):
        req.tick(now, 1, 1)
        req.on_message(wire.ack(m.MAV_RESULT_DENIED), 1, 1)
        now += 0.1
    assert [iv for _, iv in _intervals(wire)] == [20000.0, 25000.0, 31250.0]
    assert req.done and req.fallback_streams == {m.MAV_DATA_STREAM_EXTRA1}
    streams = [c for c in wire.sent if c.get_type() == "REQUEST_DATA_STREAM"]
    assert len(streams) == 1 and streams[0].req_stream_id == m.MAV_DATA_STREAM_EXTRA1


class _Ardupilot:
    """ArduPilot's answers: every SET_MESSAGE_INTERVAL faster than 40 Hz refused, slower accepted, one COMMAND_ACK
    per command in the order received, at least `lag` ticks later and one a tick (a loop that handles one command
    a pass); `intervals` is what it set (message id -> us)."""

    def __init__(self, wire: _Wire, lag: int) -> None:
        self.wire, self.lag = wire, lag
        self.queue: list[tuple[int, int, float]] = []  # (due tick, message id, interval us)
        self.intervals: dict[int, float] = {}
        self.seen = 0

    def step(self, k: int, req: StreamRequester) -> None:
        for c in self.wire.sent[self.seen:]:
            if c.get_type() == "COMMAND_LONG" and c.command == m.MAV_CMD_SET_MESSAGE_INTERVAL:
                self.queue.append((k + self.lag, int(c.param1), c.param2))
        self.seen = len(self.wire.sent)
        if self.queue and self.queue[0][0] <= k:
            _, msg_id, us = self.queue.pop(0)
            ok = us >= 1e6 / 40.0
            if ok:
                self.intervals[msg_id] = us
            req.on_message(self.wire.ack(m.MAV_RESULT_ACCEPTED if ok else m.MAV_RESULT_DENIED), 1, 1)


def test_each_answer_is_credited_to_its_own_request():
    """Three messages at 50 Hz, one at 5 Hz; the autopilot answers two ticks late. One request in flight at a time,
    so what the requester believes granted is what the autopilot set, message by message (a burst of requests
    once credited a refusal to the wrong message: RAW_IMU believed at 50 Hz, sent at its stream's 1 Hz)."""
    wire = _Wire()
    rates = {"ATTITUDE": 50.0, "SIMSTATE": 50.0, "RAW_IMU": 50.0, "VFR_HUD": 5.0}
    req = StreamRequester(wire.send, wire.ours, rates, retry_s=1.0)
    ap = _Ardupilot(wire, lag=2)
    for k in range(60):
        req.tick(k * 0.02, 1, 1)
        ap.step(k, req)
    assert req.done and not req.fallback_streams and req.late_acks == 0
    granted = req.granted()
    assert granted == {"ATTITUDE": 40.0, "SIMSTATE": 40.0, "RAW_IMU": 40.0, "VFR_HUD": 5.0}
    assert {getattr(m, f"MAVLINK_MSG_ID_{n}"): 1e6 / hz for n, hz in granted.items()} == ap.intervals


def test_one_request_in_flight_and_a_late_answer_ignored():
    wire = _Wire()
    req = StreamRequester(wire.send, wire.ours, {"RAW_IMU": 40.0, "ATTITUDE": 40.0}, retry_s=1.0)
    req.tick(0.0, 1, 1)
    req.tick(0.5, 1, 1)  # no answer yet: nothing more is sent
    assert _intervals(wire) == [(m.MAVLINK_MSG_ID_RAW_IMU, 25000.0)]
    req.tick(1.0, 1, 1)  # given up on; asked again (its second try)
    assert len(_intervals(wire)) == 2
    req.on_message(wire.ack(m.MAV_RESULT_ACCEPTED), 1, 1)
    req.on_message(wire.ack(m.MAV_RESULT_ACCEPTED), 1, 1)  # a second answer: to nothing in flight
    assert req.late_acks == 1 and req.granted() == {"RAW_IMU": 40.0}
    req.tick(1.1, 1, 1)
    req.on_message(wire.ack(m.MAV_RESULT_ACCEPTED), 1, 1)
    assert req.done and req.granted() == {"RAW_IMU": 40.0, "ATTITUDE": 40.0}
    req.reask("RAW_IMU")  # the stream watch found it slow: asked again at the granted rate
    assert not req.done
    req.tick(2.0, 1, 1)
    assert _intervals(wire)[-1] == (m.MAVLINK_MSG_ID_RAW_IMU, 25000.0)
