"""Start-up requests to the autopilot: message rates (MAV_CMD_SET_MESSAGE_INTERVAL, falling back to
REQUEST_DATA_STREAM when not acknowledged) and the GPS parameter check (PARAM_REQUEST_READ GPS1_TYPE and the
older GPS_TYPE; anything but 14 = MAV is warned about loudly). Both are driven by the daemon loop: `tick(now)`
sends what is due, `on_message(msg)` consumes answers."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable

from pymavlink import mavutil

log = logging.getLogger(__name__)
m = mavutil.mavlink

# REQUEST_DATA_STREAM groups that carry each message on ArduPilot.
_STREAM_OF = {
    "RAW_IMU": m.MAV_DATA_STREAM_RAW_SENSORS, "SCALED_IMU": m.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU2": m.MAV_DATA_STREAM_RAW_SENSORS, "SCALED_IMU3": m.MAV_DATA_STREAM_RAW_SENSORS,
    "HIGHRES_IMU": m.MAV_DATA_STREAM_RAW_SENSORS, "ATTITUDE": m.MAV_DATA_STREAM_EXTRA1,
    "GPS_RAW_INT": m.MAV_DATA_STREAM_EXTENDED_STATUS, "SYSTEM_TIME": m.MAV_DATA_STREAM_EXTENDED_STATUS,
}


@dataclass
class _Req:
    name: str
    msg_id: int
    rate_hz: float
    tries: int = 0
    acked: bool = False
    failed: bool = False


@dataclass
class StreamRequester:
    """Ask for each (message name, rate Hz) with SET_MESSAGE_INTERVAL, retrying every `retry_s`; after `tries`
    unacknowledged attempts (or a refusal) fall back to REQUEST_DATA_STREAM for that message's group."""

    send: Callable[[Any], None]
    mav: Any
    rates: dict[str, float]
    retry_s: float = 1.0
    tries: int = 3
    _reqs: dict[int, _Req] = field(default_factory=dict)
    _next: float = 0.0
    fallback_streams: set[int] = field(default_factory=set)

    def __post_init__(self) -> None:
        for name, rate in self.rates.items():
            msg_id = getattr(m, f"MAVLINK_MSG_ID_{name}")
            self._reqs[msg_id] = _Req(name, msg_id, rate)

    @property
    def done(self) -> bool:
        return all(r.acked or r.failed for r in self._reqs.values())

    def tick(self, now: float, target_system: int, target_component: int) -> None:
        if self.done or now < self._next or not target_system:
            return
        self._next = now + self.retry_s
        for r in self._reqs.values():
            if r.acked or r.failed:
                continue
            if r.tries >= self.tries:
                self._fallback(r, target_system, target_component, "not acknowledged")
                continue
            r.tries += 1
            self.send(self.mav.command_long_encode(target_system, target_component, m.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                   0, r.msg_id, 1e6 / r.rate_hz, 0, 0, 0, 0, 0))

    def _fallback(self, r: _Req, target_system: int, target_component: int, why: str) -> None:
        r.failed = True
        stream = _STREAM_OF.get(r.name, m.MAV_DATA_STREAM_ALL)
        log.warning("SET_MESSAGE_INTERVAL %s %s: falling back to REQUEST_DATA_STREAM %d at %.0f Hz", r.name, why,
                    stream, r.rate_hz)
        self.fallback_streams.add(stream)
        self.send(self.mav.request_data_stream_encode(target_system, target_component, stream,
                                                      max(1, int(round(r.rate_hz))), 1))

    def on_message(self, msg: Any, target_system: int, target_component: int) -> None:
        if msg.get_type() != "COMMAND_ACK" or msg.command != m.MAV_CMD_SET_MESSAGE_INTERVAL:
            return
        # COMMAND_ACK does not say which message it answers: credit the oldest outstanding request.
        pending = [r for r in self._reqs.values() if not (r.acked or r.failed) and r.tries > 0]
        if not pending:
            return
        r = pending[0]
        if msg.result == m.MAV_RESULT_ACCEPTED:
            r.acked = True
            log.info("autopilot sends %s at %.0f Hz", r.name, r.rate_hz)
        elif msg.result in (m.MAV_RESULT_DENIED, m.MAV_RESULT_UNSUPPORTED, m.MAV_RESULT_FAILED):
            self._fallback(r, target_system, target_component, f"refused (result {msg.result})")


GPS_TYPE_MAV = 14


@dataclass
class ParamCheck:
    """Read GPS1_TYPE (and GPS_TYPE, its pre-4.5 name) once; `warnings` collects what was found wrong.
    `value` is the first answer (None until one arrives)."""

    send: Callable[[Any], None]
    mav: Any
    names: tuple[str, ...] = ("GPS1_TYPE", "GPS_TYPE")
    retry_s: float = 2.0
    tries: int = 3
    value: float | None = None
    answered_by: str | None = None
    warnings: list[str] = field(default_factory=list)
    _tries: int = 0
    _next: float = 0.0

    @property
    def done(self) -> bool:
        return self.value is not None or self._tries >= self.tries

    def tick(self, now: float, target_system: int, target_component: int) -> None:
        if self.done or now < self._next or not target_system:
            return
        self._next = now + self.retry_s
        self._tries += 1
        for name in self.names:
            self.send(self.mav.param_request_read_encode(target_system, target_component, name.encode(), -1))
        if self._tries >= self.tries:
            log.warning("no answer to PARAM_REQUEST_READ %s: cannot check that the autopilot takes GPS_INPUT "
                        "(set GPS1_TYPE=14 on ArduPilot)", "/".join(self.names))

    def on_message(self, msg: Any) -> str | None:
        """Consume PARAM_VALUE; returns a warning text when the parameter is not 14."""
        if msg.get_type() != "PARAM_VALUE" or self.value is not None:
            return None
        pid = msg.param_id.decode() if isinstance(msg.param_id, bytes) else str(msg.param_id)
        pid = pid.rstrip("\x00")
        if pid not in self.names:
            return None
        value = float(msg.param_value)
        if not math.isfinite(value):  # a corrupt answer: keep asking
            log.warning("PARAM_VALUE %s is not finite (%r): ignored", pid, value)
            return None
        self.value, self.answered_by = value, pid
        if int(round(self.value)) != GPS_TYPE_MAV:
            text = f"{pid}={int(round(self.value))}, GPS_INPUT needs {pid}=14 (MAV): it will be ignored"
            self.warnings.append(text)
            log.error("!!! %s !!!", text)
            return text
        log.info("%s=14: the autopilot takes GPS_INPUT", pid)
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
