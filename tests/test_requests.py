"""SET_MESSAGE_INTERVAL requests as ArduPilot answers them (mavlink/requests.py): a rate it calls "too fast" is
asked for again slower (ArduPilot Rover SITL refuses 50 Hz and takes 40 Hz, issue 19), then falls back to a
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
