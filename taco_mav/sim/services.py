"""The request/answer side of the simulated ArduPilot: parameters, commands and TIMESYNC.

`AutopilotServices.handle(msg, boot_s)` takes one received message and returns the replies to send (possibly
none); it keeps the parameter table and the message intervals a companion asked for. `boot_s` is the
autopilot's clock, seconds since boot; TIMESYNC answers carry it in nanoseconds as ArduPilot does.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["AutopilotServices", "DEFAULT_PARAMS"]

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_PARAM_TYPE_INT8 = 2
MAV_PARAM_TYPE_REAL32 = 9

# name -> (value, MAV_PARAM_TYPE), ArduPilot 4.6 names. GPS1_TYPE 14 = MAVLink GPS (GPS_INPUT), GPS2_TYPE 1 = a
# real receiver (auto-detected); EK3_SRC1_POSXY 3 = GPS.
DEFAULT_PARAMS: dict[str, tuple[float, int]] = {
    "GPS1_TYPE": (14.0, MAV_PARAM_TYPE_INT8),
    "GPS2_TYPE": (1.0, MAV_PARAM_TYPE_INT8),
    "GPS_AUTO_SWITCH": (1.0, MAV_PARAM_TYPE_INT8),
    "EK3_SRC1_POSXY": (3.0, MAV_PARAM_TYPE_INT8),
    "EK3_SRC1_VELXY": (3.0, MAV_PARAM_TYPE_INT8),
    "EK3_SRC1_YAW": (1.0, MAV_PARAM_TYPE_INT8),
    "GPS1_DELAY_MS": (0.0, MAV_PARAM_TYPE_REAL32),
}


def _name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).split("\x00", 1)[0].strip()


class AutopilotServices:
    """Parameters (PARAM_REQUEST_READ / _LIST / PARAM_SET), COMMAND_LONG (SET_MESSAGE_INTERVAL, REQUEST_MESSAGE)
    and TIMESYNC, for a vehicle `sysid`/`compid`.

    `intervals` maps a message id to the interval the companion asked for, seconds (-1 = disabled, 0 = the
    default rate); `requested` collects message ids asked for once with REQUEST_MESSAGE (the simulator
    sends and clears them). `ack_log` records (command, result) of every COMMAND_ACK sent.
    """

    def __init__(self, mav: Any, sysid: int = 1, compid: int = 1, gps1_type: int = 14,
                 supported_messages: frozenset[int] = frozenset(), gps2_type: int = 1) -> None:
        self.mav = mav
        self.sysid, self.compid = sysid, compid
        self.params: dict[str, tuple[float, int]] = dict(DEFAULT_PARAMS)
        self.params["GPS1_TYPE"] = (float(gps1_type), MAV_PARAM_TYPE_INT8)
        self.params["GPS2_TYPE"] = (float(gps2_type), MAV_PARAM_TYPE_INT8)
        self.supported = supported_messages
        self.intervals: dict[int, float] = {}
        self.requested: list[int] = []
        self.ack_log: list[tuple[int, int]] = []
        self.param_sets: list[tuple[str, float]] = []

    def _for_us(self, msg: Any) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.sysid) and tc in (0, self.compid)

    def param_value(self, name: str) -> Any:
        """The PARAM_VALUE message of parameter `name` (KeyError when unknown)."""
        names = list(self.params)
        value, ptype = self.params[name]
        return self.mav.param_value_encode(name.encode("ascii"), value, ptype, len(names), names.index(name))

    def handle(self, msg: Any, boot_s: float) -> list[Any]:
        """Replies to one received message (empty for messages this side does not answer)."""
        kind = msg.get_type()
        if kind == "TIMESYNC":
            if msg.tc1 == 0:  # a request: answer with our clock, echo theirs
                return [self.mav.timesync_encode(int(round(boot_s * 1e9)), msg.ts1)]
            return []
        if kind not in ("PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "PARAM_SET", "COMMAND_LONG"):
            return []
        if not self._for_us(msg):
            return []
        if kind == "PARAM_REQUEST_LIST":
            return [self.param_value(n) for n in self.params]
        if kind == "PARAM_REQUEST_READ":
            name = _name(msg.param_id)
            if msg.param_index >= 0:
                names = list(self.params)
                name = names[msg.param_index] if msg.param_index < len(names) else ""
            if name not in self.params:
                log.debug("PARAM_REQUEST_READ of unknown parameter %r ignored", name)
                return []  # ArduPilot stays silent for unknown parameters
            return [self.param_value(name)]
        if kind == "PARAM_SET":
            name = _name(msg.param_id)
            if name not in self.params:
                log.warning("PARAM_SET of unknown parameter %r ignored", name)
                return []
            self.params[name] = (float(msg.param_value), self.params[name][1])
            self.param_sets.append((name, float(msg.param_value)))
            log.info("parameter %s set to %g", name, msg.param_value)
            return [self.param_value(name)]
        return self._command(msg)

    def _command(self, msg: Any) -> list[Any]:
        cmd = int(msg.command)
        result = MAV_RESULT_UNSUPPORTED
        if cmd == MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id, interval_us = int(msg.param1), float(msg.param2)
            if msg_id in self.supported:
                self.intervals[msg_id] = -1.0 if interval_us < 0 else interval_us * 1e-6
                result = MAV_RESULT_ACCEPTED
                log.info("message %d interval set to %g us", msg_id, interval_us)
            else:
                result = MAV_RESULT_DENIED
        elif cmd == MAV_CMD_REQUEST_MESSAGE:
            msg_id = int(msg.param1)
            if msg_id in self.supported:
                self.requested.append(msg_id)
                result = MAV_RESULT_ACCEPTED
            else:
                result = MAV_RESULT_DENIED
        self.ack_log.append((cmd, result))
        return [self.mav.command_ack_encode(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())]
