"""Which input stream feeds the estimator when the autopilot sends several of one kind: IMU (RAW_IMU,
HIGHRES_IMU, SCALED_IMU, SCALED_IMU2, SCALED_IMU3) and attitude (ATTITUDE, ATTITUDE_QUATERNION).

`SourceSelector` chooses by the first *valid* sample (one the decoders accept: finite, within physical range,
stamped), never by the first message that parses, so one corrupt message of another type arriving first
cannot lock the daemon onto a stream that never delivers. When the chosen stream has given nothing valid for
`timeout_s` seconds (companion clock) and another one delivers, the selector moves to it and says so (the
daemon logs, counts and writes an event). A pinned source (`link.imu_message`) is never left.

The stream the daemon asked the autopilot for (`preferred`) is returned to as soon as it streams steadily:
STEADY_SAMPLES valid samples in a row, each stamped within STEADY_DT_S (autopilot time) after the last. Until
its SET_MESSAGE_INTERVAL is granted every stream comes at its serial port's default rate (ArduPilot's SRn_*:
1-4 Hz), so the first sample may be another stream's, and a 1 Hz stream looks silent for a second: without the
return, a CI run chose RAW_IMU at 1 Hz, fell back to SCALED_IMU2 before RAW_IMU's 40 Hz was granted, and fed
the estimator one sample a second for 150 s (each one a time jump, none used), and a restarted daemon sat on
SCALED_IMU2 until EKF3 failed safe.

`attitude_quaternion` decodes ATTITUDE_QUATERNION (w, x, y, z: the rotation from NED to body FRD; body rates
FRD rad/s; time_boot_ms) into the same `AttitudeReading` (ZYX Euler roll, pitch, yaw, NED radians) as ATTITUDE.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

from taco_mav.mavlink.decoders import IMU_MESSAGES, MAX_GYRO, AttitudeReading, Decoders, ImuReading, euler_rates

log = logging.getLogger(__name__)

__all__ = ["ATTITUDE_MESSAGES", "ATTITUDE_REQUESTED", "ATTITUDE_STALE_S", "IMU_REQUESTED", "InputSources",
           "SOURCE_TIMEOUT_S", "STEADY_DT_S", "STEADY_SAMPLES", "SourceSelector", "Switch", "attitude_quaternion"]

ATTITUDE_MESSAGES = ("ATTITUDE", "ATTITUDE_QUATERNION")
ATTITUDE_REQUESTED = "ATTITUDE"  # the attitude stream the daemon asks for
IMU_REQUESTED = "RAW_IMU"  # the IMU stream the daemon asks for when link.imu_message is "auto"
SOURCE_TIMEOUT_S = 1.0  # s (companion clock) without a valid sample from the chosen source before another is taken
ATTITUDE_STALE_S = 1.0  # autopilot s: an IMU sample paired with an attitude this much older is counted stale
STEADY_DT_S = 0.2  # autopilot s: the preferred stream at 5 Hz or faster streams (defaults 1-4 Hz; asked >= 10 Hz)
STEADY_SAMPLES = 5  # valid samples in a row that close together: the preferred stream is back (a stray one is not)
QUAT_NORM_TOL = 0.1  # |q| outside 1 +- this is not a rotation (corrupt): refused


@dataclass(frozen=True)
class Switch:
    """A change of source: `old` (None at the first choice) -> `new`; silent_s: how long `old` had given
    nothing valid, s (0 at the first choice)."""

    old: str | None
    new: str
    silent_s: float


class SourceSelector:
    """Chooses one of `kinds` (message names) by the first valid sample and falls back after `timeout_s`.

    pinned: a name of `kinds` to use whatever happens (None: choose). preferred: the one asked for, returned to
    when it streams steadily (None: none). `offer(kind, valid, now, stamp)` is called for every message of
    `kinds` (valid: the decoders accepted it; now: companion s; stamp: the sample's autopilot s) and says whether
    to use this sample; a change of source is then in `take_switch()`. `switches` counts changes after the first
    choice.
    """

    def __init__(self, kinds: tuple[str, ...], pinned: str | None = None, timeout_s: float = SOURCE_TIMEOUT_S,
                 preferred: str | None = None) -> None:
        for name in (pinned, preferred):
            if name is not None and name not in kinds:
                raise ValueError(f"source {name!r} is not one of {kinds}")
        self.kinds, self.pinned, self.timeout_s = kinds, pinned, timeout_s
        self.preferred = pinned or preferred
        self.current: str | None = pinned
        self.switches = 0
        self.invalid: dict[str, int] = {}  # per kind: samples refused by the decoders
        self._last_valid: dict[str, float] = {}
        self._steady = 0  # the preferred stream's valid samples in a row, each within STEADY_DT_S of the last
        self._steady_stamp = -math.inf  # autopilot s of the preferred stream's last valid sample
        self._chosen_at = -math.inf
        self._switch: Switch | None = None

    def offer(self, kind: str, valid: bool, now: float, stamp: float = math.nan) -> bool:
        """One message of `kind` arrived at `now` (companion s), its sample stamped `stamp` (autopilot s); True
        when its sample is to be used."""
        if kind == self.preferred:
            close = valid and 0.0 < stamp - self._steady_stamp <= STEADY_DT_S
            self._steady = self._steady + 1 if close else int(valid)
            if valid:
                self._steady_stamp = stamp
        if not valid:
            self.invalid[kind] = self.invalid.get(kind, 0) + 1
            return False
        last = self._last_valid.get(self.current, -math.inf) if self.current is not None else -math.inf
        self._last_valid[kind] = now
        if kind == self.current:
            return True
        if self.pinned is not None:
            return False
        if self.current is None:
            self._take(kind, now, 0.0)
            return True
        if kind == self.preferred and self._steady >= STEADY_SAMPLES:
            self.switches += 1
            self._take(kind, now, max(0.0, now - last))
            return True
        silent = now - max(last, self._chosen_at)
        if silent > self.timeout_s:
            self.switches += 1
            self._take(kind, now, silent)
            return True
        return False

    def _take(self, kind: str, now: float, silent_s: float) -> None:
        self._switch = Switch(self.current, kind, silent_s)
        self.current, self._chosen_at = kind, now

    def take_switch(self) -> Switch | None:
        """The change of source since the last call (None: none)."""
        out, self._switch = self._switch, None
        return out

    def silent_s(self, now: float) -> float:
        """Seconds (companion) since the chosen source last gave a valid sample (inf before any)."""
        if self.current is None:
            return math.inf
        return now - self._last_valid.get(self.current, -math.inf)

    def summary(self) -> dict[str, Any]:
        return {"source": self.current, "switches": self.switches, "invalid": dict(self.invalid)}


def attitude_quaternion(msg: Any, decoders: Decoders) -> AttitudeReading | None:
    """ATTITUDE_QUATERNION -> AttitudeReading (ZYX Euler, NED radians; Euler rates from the FRD body rates), or
    None (counted in decoders.rejected as ATTITUDE_QUATERNION:<reason>) when not finite or not a rotation."""
    kind = "ATTITUDE_QUATERNION"
    q = [float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4)]
    if not all(math.isfinite(v) for v in q):
        decoders.reject(kind, "nonfinite")
        return None
    norm = math.sqrt(sum(v * v for v in q))
    if not abs(norm - 1.0) <= QUAT_NORM_TOL:
        decoders.reject(kind, "range")
        return None
    w, x, y, z = (v / norm for v in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    body = (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed))
    rates = (0.0, 0.0, 0.0)
    if all(math.isfinite(v) for v in body) and max(abs(v) for v in body) <= MAX_GYRO:
        rates = euler_rates(roll, pitch, *body)
    else:
        decoders.reject(kind, "rates")  # the angles are still used, without carrying them in time
    return AttitudeReading(msg.time_boot_ms * 1e-3, roll, pitch, yaw, rates)


class InputSources:
    """The daemon's two selectors: `imu` over IMU_MESSAGES (pinned by `link.imu_message` unless "auto"; else
    IMU_REQUESTED preferred) and `attitude` over ATTITUDE_MESSAGES (ATTITUDE_REQUESTED preferred). The readings
    come out decoded (SI units, autopilot seconds) or None when the message is refused or not from the chosen
    source; `take_switches()` gives the changes since the last call as ("imu" | "attitude", Switch)."""

    def __init__(self, imu_message: str = "auto", timeout_s: float = SOURCE_TIMEOUT_S) -> None:
        self.imu = SourceSelector(IMU_MESSAGES, None if imu_message == "auto" else imu_message, timeout_s,
                                  preferred=IMU_REQUESTED)
        self.attitude = SourceSelector(ATTITUDE_MESSAGES, None, timeout_s, preferred=ATTITUDE_REQUESTED)

    def imu_reading(self, msg: Any, decoders: Decoders, now: float) -> ImuReading | None:
        """An IMU message arrived at `now` (companion s): its reading when it is to be integrated."""
        kind = msg.get_type()
        if kind == "RAW_IMU" and getattr(msg, "id", 0) != 0:  # a second IMU's RAW_IMU: not a source of ours
            return None
        if self.imu.pinned is not None and kind != self.imu.pinned:
            return None
        r = decoders.imu(msg)
        return r if self.imu.offer(kind, r is not None, now, r.t if r is not None else math.nan) else None

    def attitude_reading(self, msg: Any, decoders: Decoders, now: float) -> AttitudeReading | None:
        """An ATTITUDE or ATTITUDE_QUATERNION arrived at `now` (companion s): its reading when it is to be used."""
        kind = msg.get_type()
        a = decoders.attitude(msg) if kind == "ATTITUDE" else attitude_quaternion(msg, decoders)
        return a if self.attitude.offer(kind, a is not None, now, a.t if a is not None else math.nan) else None

    def take_switches(self) -> list[tuple[str, Switch]]:
        return [(name, sw) for name, sel in (("imu", self.imu), ("attitude", self.attitude))
                if (sw := sel.take_switch()) is not None]

    def summary(self) -> dict[str, Any]:
        return {"imu": self.imu.summary(), "attitude": self.attitude.summary()}
