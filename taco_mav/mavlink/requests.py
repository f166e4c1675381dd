"""Start-up requests to the autopilot: message rates (MAV_CMD_SET_MESSAGE_INTERVAL, falling back to
REQUEST_DATA_STREAM when not acknowledged), one-off messages (MAV_CMD_REQUEST_MESSAGE, repeated while wanted:
GPS_GLOBAL_ORIGIN and HOME_POSITION until the daemon has an origin) and the GPS parameter check
(PARAM_REQUEST_READ GPS1_TYPE / GPS2_TYPE and their pre-4.6 names GPS_TYPE / GPS_TYPE2: which GPS instance is
ours, fed by GPS_INPUT, and which is a real receiver; ours anything but 14 = MAV is warned about loudly). All
are driven by the daemon loop: `tick(now)` sends what is due, `on_message(msg)` consumes answers."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable

from pymavlink import mavutil

from taco_mav.mavlink.mavconst import GPS_TYPE_MAV
from taco_mav.mavlink.param_read import ParamRead

log = logging.getLogger(__name__)
m = mavutil.mavlink

# REQUEST_DATA_STREAM groups that carry each message on ArduPilot.
_STREAM_OF = {
    "RAW_IMU": m.MAV_DATA_STREAM_RAW_SENSORS, "SCALED_IMU": m.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU2": m.MAV_DATA_STREAM_RAW_SENSORS, "SCALED_IMU3": m.MAV_DATA_STREAM_RAW_SENSORS,
    "HIGHRES_IMU": m.MAV_DATA_STREAM_RAW_SENSORS, "ATTITUDE": m.MAV_DATA_STREAM_EXTRA1,
    "GPS_RAW_INT": m.MAV_DATA_STREAM_EXTENDED_STATUS, "SYSTEM_TIME": m.MAV_DATA_STREAM_EXTENDED_STATUS,
    "GPS2_RAW": m.MAV_DATA_STREAM_EXTENDED_STATUS, "SIMSTATE": m.MAV_DATA_STREAM_EXTRA1,
    "VFR_HUD": m.MAV_DATA_STREAM_EXTRA2, "SERVO_OUTPUT_RAW": m.MAV_DATA_STREAM_RC_CHANNELS,
    "GLOBAL_POSITION_INT": m.MAV_DATA_STREAM_POSITION,
    # Rover's EXTRA1 group at ArduPilot 03494bd (measured: it comes with ATTITUDE; SET_MESSAGE_INTERVAL and
    # MAV_CMD_REQUEST_MESSAGE are refused there, "No ap_message for mavlink id (9000)"); older Rovers: EXTRA3
    "WHEEL_DISTANCE": m.MAV_DATA_STREAM_EXTRA1,
    # sent on change and on MAV_CMD_REQUEST_MESSAGE only: no stream group to fall back to
    "HOME_POSITION": None, "GPS_GLOBAL_ORIGIN": None,
}


@dataclass
class _Req:
    name: str
    msg_id: int
    rate_hz: float
    tries: int = 0
    acked: bool = False
    failed: bool = False
    slower: int = 0  # times the rate was lowered after a refusal


@dataclass
class StreamRequester:
    """Ask for each (message name, rate Hz) with SET_MESSAGE_INTERVAL, one request in flight at a time, retrying
    after `retry_s` without an answer; after `tries` unacknowledged attempts (or a refusal) fall back to
    REQUEST_DATA_STREAM for that message's group. A refusal is first answered by asking again at `slower_factor`
    times the rate, up to `slower_tries` times: ArduPilot refuses intervals shorter than 1.25 scheduler periods
    ("too fast": 40 Hz at most on a 50 Hz Rover), and an interval it accepts beats a data stream of unknown rate.

    One at a time because COMMAND_ACK names the command, not the message it was about: with several requests in
    flight an answer cannot be told apart (MAVSDK keeps one command per id in flight for the same reason). A
    burst once credited ArduPilot's refusal of RAW_IMU at 50 Hz to ATTITUDE and its acceptance of ATTITUDE to
    RAW_IMU: the daemon believed RAW_IMU came at 50 Hz while it came at its stream's 1 Hz (a CI run of
    tests/test_sitl.py, EKF3 never had a position). An answer that comes after its request was given up on is
    ignored. `reask(name)` asks again for a message already granted (the daemon's stream watch: it stopped
    arriving at its rate)."""

    send: Callable[[Any], None]
    mav: Any
    rates: dict[str, float]
    retry_s: float = 1.0
    tries: int = 3
    slower_factor: float = 0.8
    slower_tries: int = 2
    _reqs: dict[int, _Req] = field(default_factory=dict)
    _in_flight: _Req | None = None
    _sent_at: float = -math.inf
    fallback_streams: set[int] = field(default_factory=set)
    late_acks: int = 0  # answers to a request given up on (ignored)

    def __post_init__(self) -> None:
        for name, rate in self.rates.items():
            msg_id = getattr(m, f"MAVLINK_MSG_ID_{name}")
            self._reqs[msg_id] = _Req(name, msg_id, rate)

    @property
    def done(self) -> bool:
        return all(r.acked or r.failed for r in self._reqs.values())

    def granted(self) -> dict[str, float]:
        """Message name -> the rate (Hz) the autopilot accepted, for each message granted by SET_MESSAGE_INTERVAL
        (not those left to a data stream or still asked for)."""
        return {r.name: r.rate_hz for r in self._reqs.values() if r.acked}

    def reask(self, name: str) -> None:
        """Ask for `name` again at the rate last granted (a stream that stopped arriving at it)."""
        for r in self._reqs.values():
            if r.name == name and r.acked:
                r.acked, r.tries = False, 0

    def tick(self, now: float, target_system: int, target_component: int) -> None:
        if self.done or not target_system:
            return
        if self._in_flight is not None and now - self._sent_at < self.retry_s:
            return  # the answer to the request in flight is awaited
        self._in_flight = None
        for r in self._reqs.values():
            if r.acked or r.failed:
                continue
            if r.tries >= self.tries:
                self._fallback(r, target_system, target_component, "not acknowledged")
                continue
            r.tries += 1
            self.send(self.mav.command_long_encode(target_system, target_component, m.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                   0, r.msg_id, 1e6 / r.rate_hz, 0, 0, 0, 0, 0))
            self._in_flight, self._sent_at = r, now
            return

    def _fallback(self, r: _Req, target_system: int, target_component: int, why: str) -> None:
        r.failed = True
        stream = _STREAM_OF.get(r.name, m.MAV_DATA_STREAM_ALL)
        if stream is None:
            log.info("SET_MESSAGE_INTERVAL %s %s: asked for with MAV_CMD_REQUEST_MESSAGE only", r.name, why)
            return
        log.warning("SET_MESSAGE_INTERVAL %s %s: falling back to REQUEST_DATA_STREAM %d at %.0f Hz", r.name, why,
                    stream, r.rate_hz)
        self.fallback_streams.add(stream)
        self.send(self.mav.request_data_stream_encode(target_system, target_component, stream,
                                                      max(1, int(round(r.rate_hz))), 1))

    def on_message(self, msg: Any, target_system: int, target_component: int) -> None:
        if msg.get_type() != "COMMAND_ACK" or msg.command != m.MAV_CMD_SET_MESSAGE_INTERVAL:
            return
        r = self._in_flight
        if r is None:  # the answer to a request given up on: which message it was about is unknown
            self.late_acks += 1
            return
        self._in_flight = None  # the next request goes at the next tick
        if msg.result == m.MAV_RESULT_ACCEPTED:
            r.acked = True
            log.info("autopilot sends %s at %.0f Hz", r.name, r.rate_hz)
        elif msg.result == m.MAV_RESULT_DENIED and r.slower < self.slower_tries and r.rate_hz > 1.0:
            r.slower += 1
            r.tries = 0
            log.info("autopilot refused %s at %.0f Hz: asking for %.0f Hz", r.name, r.rate_hz,
                     r.rate_hz * self.slower_factor)
            r.rate_hz *= self.slower_factor
        elif msg.result in (m.MAV_RESULT_DENIED, m.MAV_RESULT_UNSUPPORTED, m.MAV_RESULT_FAILED):
            self._fallback(r, target_system, target_component, f"refused (result {msg.result})")


# Asked for beside the daemon's inputs, for real GNSS: the second GPS instance and the offered origins.
GNSS_RATES = {"GPS2_RAW": 2.0, "HOME_POSITION": 0.5, "GPS_GLOBAL_ORIGIN": 0.5}


@dataclass
class MessageRequest:
    """MAV_CMD_REQUEST_MESSAGE for each of `names` every `retry_s` while `tick(..., wanted=True)` (the daemon:
    GPS_GLOBAL_ORIGIN and HOME_POSITION until it has an origin; an autopilot without them stays silent)."""

    send: Callable[[Any], None]
    mav: Any
    names: tuple[str, ...]
    retry_s: float = 2.0
    sent: int = 0
    _next: float = -math.inf

    def tick(self, now: float, target_system: int, target_component: int, wanted: bool = True) -> None:
        if not wanted or not target_system or now < self._next:
            return
        self._next = now + self.retry_s
        for name in self.names:
            msg_id = getattr(m, f"MAVLINK_MSG_ID_{name}")
            self.send(self.mav.command_long_encode(target_system, target_component, m.MAV_CMD_REQUEST_MESSAGE, 0,
                                                   msg_id, 0, 0, 0, 0, 0, 0))
            self.sent += 1


# GPS instance (1 = GPS1) -> the key its type is read under; ArduPilot 4.6 renamed GPS_TYPE / GPS_TYPE2 to
# GPS1_TYPE / GPS2_TYPE, and ParamCheck asks for both names
GPS_TYPE_KEYS = {1: "GPS1_TYPE", 2: "GPS2_TYPE"}


# Antenna offsets differing from output.antenna_frd_m by more than this (metres, any axis) are warned about.
ANTENNA_TOLERANCE_M = 0.05


class ParamCheck:
    """Read the GPS type of both instances once (GPS1_TYPE / GPS2_TYPE, or GPS_TYPE / GPS_TYPE2 on firmware
    before 4.6; the autopilot answers the names it has) through a `ParamRead`. `gps_id` is the profile's
    output.gps_id: our GPS_INPUT goes to instance gps_id + 1, whose type must be 14 (MAV), else `warnings` says so.
    `types`: instance -> GPSn_TYPE as answered; `value` / `answered_by`: our instance's type and the parameter
    that gave it (None until answered).

    With `antenna_frd_m` (the profile's output.antenna_frd_m, body FRD metres) it also reads our instance's
    antenna offset, GPS{n}_POS_X/Y/Z (GPS_POS{n}_X/Y/Z before 4.6): EKF3 takes GPS_INPUT as the position of that
    point, so a profile that sends another point is warned about (`antenna_warning`) when any axis differs by more
    than ANTENNA_TOLERANCE_M. `antenna`: axis ("X", "Y", "Z") -> metres as answered."""

    def __init__(self, send: Callable[[Any], None], mav: Any, gps_id: int = 0,
                 antenna_frd_m: tuple[float, float, float] | None = None, retry_s: float = 2.0,
                 tries: int = 3) -> None:
        self.gps_id, self.antenna_frd_m = gps_id, antenna_frd_m
        n = self.instance
        self._axis = {} if antenna_frd_m is None else {f"GPS{n}_POS_{a}": a for a in "XYZ"}
        self.read = ParamRead(send, mav, [("GPS1_TYPE", "GPS_TYPE"), ("GPS2_TYPE", "GPS_TYPE2"),
                                          *((key, f"GPS_POS{n}_{a}") for key, a in self._axis.items())],
                              retry_s, tries)
        self.value: float | None = None
        self.answered_by: str | None = None
        self.types: dict[int, int] = {}
        self.warnings: list[str] = []
        self.antenna: dict[str, float] = {}
        self.antenna_warning: str | None = None

    @property
    def instance(self) -> int:
        """Our GPS instance, 1-based (GPS1 = 1)."""
        return self.gps_id + 1

    @property
    def antenna_names(self) -> dict[str, str]:
        """Parameter name -> axis of our instance's antenna offset (4.6 and later, then older firmware); empty
        without antenna_frd_m."""
        return {name: axis for key, axis in self._axis.items() for name in self.read.groups[key]}

    @property
    def done(self) -> bool:
        return self.read.done

    def tick(self, now: float, target_system: int, target_component: int) -> None:
        missing = self.read.tick(now, target_system, target_component)
        if GPS_TYPE_KEYS[self.instance] in missing:
            log.warning("no answer to PARAM_REQUEST_READ GPS%d_TYPE: cannot check that the autopilot takes GPS_INPUT "
                        "(set GPS%d_TYPE=14 on ArduPilot)", self.instance, self.instance)
        if any(key in self._axis for key in missing):
            log.info("no answer to PARAM_REQUEST_READ GPS%d_POS_X/Y/Z: the antenna offset is not checked against "
                     "output.antenna_frd_m", self.instance)

    def _on_antenna(self, pid: str, axis: str, value: float) -> str | None:
        """One antenna-offset parameter; once all three axes are known, the warning text when they differ from
        output.antenna_frd_m by more than ANTENNA_TOLERANCE_M (else None)."""
        assert self.antenna_frd_m is not None
        self.antenna[axis] = value
        if len(self.antenna) < 3:
            return None
        ap = (self.antenna["X"], self.antenna["Y"], self.antenna["Z"])
        ours = tuple(float(v) for v in self.antenna_frd_m)
        diff = max(abs(a - b) for a, b in zip(ap, ours))
        if diff <= ANTENNA_TOLERANCE_M:
            log.info("GPS%d antenna offset matches output.antenna_frd_m", self.instance)
            return None
        stem = pid[:-2]  # GPS1_POS or GPS_POS1
        text = (f"antenna off {diff:.2f} m: {stem}_X/Y/Z={ap[0]:.2f},{ap[1]:.2f},{ap[2]:.2f} but "
                f"output.antenna_frd_m={ours[0]:.2f},{ours[1]:.2f},{ours[2]:.2f}: the position sent is not the point "
                f"the autopilot expects (copy {stem}_X/Y/Z into the profile)")
        self.antenna_warning = text
        self.warnings.append(text)
        log.warning("%s", text)
        return text

    def is_mav(self, instance: int) -> bool | None:
        """True when GPS instance `instance` (1-based) is of type 14 (fed by GPS_INPUT), None while unknown."""
        t = self.types.get(instance)
        return None if t is None else t == GPS_TYPE_MAV

    def on_message(self, msg: Any) -> str | None:
        """Consume PARAM_VALUE; returns a warning text when our instance's type is not 14, or when its antenna
        offset differs from output.antenna_frd_m (`antenna_warning`)."""
        answer = self.read.on_message(msg)
        if answer is None:
            return None
        key, value = answer
        pid = self.read.answered_by[key]
        if key in self._axis:
            return self._on_antenna(pid, self._axis[key], value)
        instance = 1 if key == GPS_TYPE_KEYS[1] else 2
        self.types[instance] = int(round(value))
        if instance != self.instance:
            return None
        self.value, self.answered_by = value, pid
        if self.types[instance] != GPS_TYPE_MAV:
            text = f"{pid}={self.types[instance]}, GPS_INPUT needs {pid}=14 (MAV): it will be ignored"
            self.warnings.append(text)
            log.error("!!! %s !!!", text)
            return text
        log.info("%s=14: the autopilot takes GPS_INPUT as GPS%d", pid, instance)
        return None


def ekf3_gate_warnings(satellites: int, hdop_uere_m: float, hdop_min: float) -> list[str]:
    """Configuration that would keep EKF3 from ever using our GPS_INPUT (>= 6 sats, HDOP <= 2.5, hacc <= 5 m)."""
    out = []
    if satellites < 6:
        out.append(f"output.satellites_visible={satellites} < 6: EKF3 will never use this GPS")
    if hdop_min > 2.5:
        out.append(f"output.hdop_min={hdop_min} > 2.5: EKF3 will never use this GPS")
    if 5.0 / hdop_uere_m > 2.5 + 1e-9:
        out.append(f"output.hdop_uere_m={hdop_uere_m}: an accuracy of 5 m maps to HDOP {5.0 / hdop_uere_m:.2f} > 2.5; "
                   "EKF3 drops this GPS before its 5 m accuracy gate does")
    return out
