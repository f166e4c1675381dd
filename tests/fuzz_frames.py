"""Test tooling, not product code (used by fuzz_harness.py and the tests).

Fuzz frames for the daemon: a seeded valid autopilot stream and seeded mutated / random MAVLink frames.

`AutopilotStream` is a level ArduPilot rover driving a straight line (heading `yaw_deg` true, `speed` m/s) seen
from its MAVLink side: per 10 ms step of autopilot time it emits the IMU message of the episode's kind (100 Hz),
ATTITUDE (50 Hz), SIMSTATE (10 Hz), HEARTBEAT / SYSTEM_TIME / a TIMESYNC request (1 Hz) and GPS2_RAW (a real
receiver as GPS2, 4 Hz for the first second; GPS1 = GPS_RAW_INT is the daemon's own GPS_INPUT).
Every frame is sysid 1, compid 1, MAVLink 2, as raw bytes.

`Mutator.frame()` draws one mutation (see MUTATIONS) and returns its name and the datagrams to send. Everything
random comes from one `random.Random(seed)`: the same seed gives the same bytes.
"""

from __future__ import annotations

import math
import os
import random
from collections import deque
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

m = mavlink
G0 = 9.80665
STEP_S = 0.01  # autopilot seconds per stream step (100 Hz IMU)
TARGETS = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "ATTITUDE", "GPS_RAW_INT", "GPS2_RAW", "SYSTEM_TIME",
           "TIMESYNC", "SIMSTATE", "HEARTBEAT", "COMMAND_ACK", "PARAM_VALUE")
MUTATIONS = ("random_bytes", "bit_flip", "truncate", "bad_crc", "unknown_id", "field_values", "nonfinite",
             "zero_dt", "negative_dt", "time_back", "time_forward", "duplicate", "reorder", "foreign_source",
             "concat", "split", "mavlink1")
_INT_RANGE = {"uint8_t": (0, 2**8 - 1), "int8_t": (-2**7, 2**7 - 1), "uint16_t": (0, 2**16 - 1),
              "int16_t": (-2**15, 2**15 - 1), "uint32_t": (0, 2**32 - 1), "int32_t": (-2**31, 2**31 - 1),
              "uint64_t": (0, 2**64 - 1), "int64_t": (-2**63, 2**63 - 1)}
_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 3.4e38, -3.4e38, 1e-45, 1e6, -1e6)


class AutopilotStream:
    """The valid stream. t: autopilot seconds (boot_s at step 0); lat0, lon0: degrees; alt0: metres AMSL."""

    def __init__(self, imu_kind: str, boot_s: float = 100.0, lat0: float = 49.0, lon0: float = 8.4,
                 alt0: float = 115.0, yaw_deg: float = 30.0, speed: float = 5.0, sysid: int = 1, compid: int = 1) -> None:
        if imu_kind not in ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU"):
            raise ValueError(f"imu_kind {imu_kind!r}: expected HIGHRES_IMU, RAW_IMU or SCALED_IMU")
        self.imu_kind, self.boot_s = imu_kind, boot_s
        self.lat0, self.lon0, self.alt0 = lat0, lon0, alt0
        self.yaw, self.speed = math.radians(yaw_deg), speed
        self.tx = m.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.k = 0

    @property
    def t(self) -> float:
        return self.boot_s + self.k * STEP_S

    def latlon(self, t: float) -> tuple[float, float]:
        """Truth at autopilot time t (flat-earth metres -> degrees; plenty for a fuzz run)."""
        d = self.speed * max(t - self.boot_s, 0.0)
        north, east = d * math.cos(self.yaw), d * math.sin(self.yaw)
        return (self.lat0 + north / 111_320.0,
                self.lon0 + east / (111_320.0 * math.cos(math.radians(self.lat0))))

    def message(self, kind: str, t: float | None = None) -> Any:
        """A plausible message of `kind` at autopilot time t (default: now)."""
        t = self.t if t is None else t
        us, ms, tx = max(int(t * 1e6), 0), min(max(int(t * 1e3), 0), 2**32 - 1), self.tx
        lat, lon = (min(max(v, -180.0), 180.0) for v in self.latlon(t))  # far-future times: keep int32 degE7
        if kind == "RAW_IMU":
            return tx.raw_imu_encode(us, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
        if kind == "SCALED_IMU":
            return tx.scaled_imu_encode(ms, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
        if kind == "HIGHRES_IMU":
            return tx.highres_imu_encode(us, 0.0, 0.0, -G0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 1013.0, 0.0, 115.0, 25.0,
                                         0x3F)
        if kind == "ATTITUDE":
            return tx.attitude_encode(ms, 0.0, 0.0, self.yaw, 0.0, 0.0, 0.0)
        if kind == "GPS_RAW_INT":
            return tx.gps_raw_int_encode(us, 3, int(lat * 1e7), int(lon * 1e7), int(self.alt0 * 1e3), 80, 120,
                                         int(self.speed * 100), int(math.degrees(self.yaw) * 100), 12)
        if kind == "GPS2_RAW":
            return tx.gps2_raw_encode(us, 3, int(lat * 1e7), int(lon * 1e7), int(self.alt0 * 1e3), 80, 120,
                                      int(self.speed * 100), int(math.degrees(self.yaw) * 100), 12, 0, 0)
        if kind == "SYSTEM_TIME":
            return tx.system_time_encode(1_700_000_000_000_000 + us, ms)
        if kind == "TIMESYNC":
            return tx.timesync_encode(0, int(t * 1e9))
        if kind == "SIMSTATE":
            return tx.simstate_encode(0.0, 0.0, self.yaw, 0.0, 0.0, -G0, 0.0, 0.0, 0.0, int(lat * 1e7), int(lon * 1e7))
        if kind == "HEARTBEAT":
            return tx.heartbeat_encode(m.MAV_TYPE_GROUND_ROVER, m.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, m.MAV_STATE_ACTIVE)
        if kind == "COMMAND_ACK":
            return tx.command_ack_encode(m.MAV_CMD_SET_MESSAGE_INTERVAL, m.MAV_RESULT_ACCEPTED)
        if kind == "PARAM_VALUE":
            return tx.param_value_encode(b"GPS1_TYPE", 14.0, m.MAV_PARAM_TYPE_INT8, 900, 1)
        raise ValueError(f"no plausible {kind}")

    def pack(self, msg: Any, mavlink1: bool = False) -> bytes:
        """Raw frame bytes with our identity and the next sequence number."""
        buf = bytes(msg.pack(self.tx, force_mavlink1=mavlink1))
        self.tx.seq = (self.tx.seq + 1) % 256
        return buf

    def step(self) -> list[bytes]:
        """The frames of one 10 ms step (then the clock advances)."""
        k, out = self.k, []
        if k % 100 == 0:
            out += [self.pack(self.message(kind)) for kind in ("HEARTBEAT", "SYSTEM_TIME", "TIMESYNC")]
        if k <= 100 and k % 25 == 0:
            out.append(self.pack(self.message("GPS2_RAW")))
        if k % 2 == 0:
            out.append(self.pack(self.message("ATTITUDE")))
        if k % 10 == 0:
            out.append(self.pack(self.message("SIMSTATE")))
        out.append(self.pack(self.message(self.imu_kind)))
        self.k += 1
        return out


IMU_KINDS = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")


def corrupt_imu(stream: AutopilotStream, rng: random.Random) -> bytes:
    """One IMU message of any kind that decodes but is not a valid sample: NaN/inf fields (HIGHRES_IMU),
    accelerations or rates beyond the sensor's range, a zero timestamp, or every axis exactly zero; stamped
    near the stream's time (the kind of message that must not choose the daemon's IMU source)."""
    kind = rng.choice(IMU_KINDS)
    us, ms, tx = int(stream.t * 1e6), int(stream.t * 1e3), stream.tx
    how = rng.choice(("range", "zero_time", "all_zero") + (("nonfinite",) * 3 if kind == "HIGHRES_IMU" else ()))
    if kind == "HIGHRES_IMU":
        bad = rng.choice((math.nan, math.inf, -math.inf))
        acc = {"nonfinite": (bad, 0.0, -G0), "range": (0.0, 0.0, -20.0 * G0), "zero_time": (0.0, 0.0, -G0),
               "all_zero": (0.0, 0.0, 0.0)}[how]
        gyr = (0.0, bad, 0.0) if how == "nonfinite" else (0.0, 0.0, 0.0)
        msg = tx.highres_imu_encode(0 if how == "zero_time" else us, *acc, *gyr, 0.0, 0.0, 0.0, 1013.0, 0.0, 115.0,
                                    25.0, 0x3F)
    else:
        acc = {"range": (0, 0, rng.choice((-32768, 32767))), "zero_time": (0, 0, -1000), "all_zero": (0, 0, 0)}[how]
        gyr = (0, rng.choice((-32768, 32767)), 0) if how == "range" else (0, 0, 0)  # 32.8 rad/s: within range
        t = 0 if how == "zero_time" else (us if kind == "RAW_IMU" else ms)
        encode = getattr(tx, f"{kind.lower()}_encode")
        msg = encode(t, *acc, *gyr, 0, 0, 0)
    return stream.pack(msg)


class Mutator:
    """Seeded fuzz frames around a stream: `frame()` -> (mutation name, datagrams). `recent` holds the last valid
    frames sent (the caller appends them) for duplicates and late (reordered) arrivals."""

    def __init__(self, stream: AutopilotStream, seed: int, mutations: tuple[str, ...] = MUTATIONS) -> None:
        unknown = [name for name in mutations if name not in MUTATIONS]
        if unknown or not mutations:
            raise ValueError(f"mutations {unknown or '()'}: expected some of {', '.join(MUTATIONS)}")
        self.stream = stream
        self.mutations = tuple(mutations)
        self.rng = random.Random(seed)
        self.recent: deque[bytes] = deque(maxlen=64)
        self._unknown_ids = [i for i in range(1, 2**16) if i not in m.mavlink_map]

    def frame(self) -> tuple[str, list[bytes]]:
        name = self.rng.choice(self.mutations)
        return name, getattr(self, f"_{name}")()

    # ------------------------------------------------------------------ helpers
    def _valid(self, kind: str | None = None, t: float | None = None) -> Any:
        return self.stream.message(kind or self.rng.choice(TARGETS), t)

    def _value(self, ftype: str, current: Any) -> Any:
        r = self.rng
        if ftype == "float" or ftype == "double":
            return r.choice(_FLOATS) if r.random() < 0.7 else r.gauss(0.0, 1.0) * r.choice((1.0, 100.0, 1e5))
        if ftype == "char":
            return bytes(r.randrange(256) for _ in range(r.randrange(0, 17)))
        lo, hi = _INT_RANGE[ftype]
        return r.choice((lo, hi, 0, r.randint(lo, hi), current if isinstance(current, int) else 0))

    def _with_fields(self, msg: Any, floats_only: bool) -> bytes:
        fields = [(f, t) for f, t, n in zip(msg.fieldnames, msg.fieldtypes, msg.array_lengths)
                  if n == 0 and (t == "float" or not floats_only)]
        if not fields:
            fields = [(f, t) for f, t, n in zip(msg.fieldnames, msg.fieldtypes, msg.array_lengths) if n == 0]
        chosen = [fields[self.rng.randrange(len(fields))]] + [f for f in fields if self.rng.random() < 0.2]
        for fname, ftype in chosen:
            if floats_only and ftype == "float":
                setattr(msg, fname, self.rng.choice((math.nan, math.inf, -math.inf)))
            else:
                setattr(msg, fname, self._value(ftype, getattr(msg, fname)))
        return self.stream.pack(msg)

    def _timed(self, t: float) -> bytes:
        kind = self.stream.imu_kind if self.rng.random() < 0.7 else self.rng.choice(("ATTITUDE", "SYSTEM_TIME",
                                                                                     "GPS2_RAW", "SIMSTATE"))
        return self.stream.pack(self._valid(kind, t))

    # ------------------------------------------------------------------ mutations
    def _random_bytes(self) -> list[bytes]:
        r = self.rng
        body = bytes(r.randrange(256) for _ in range(r.randrange(0, 280)))
        return [bytes([r.choice((0xFD, 0xFE))]) + body if r.random() < 0.5 else body]

    def _bit_flip(self) -> list[bytes]:
        buf = bytearray(self.stream.pack(self._valid()))
        for _ in range(self.rng.randint(1, 8)):
            i = self.rng.randrange(len(buf) * 8)
            buf[i // 8] ^= 1 << (i % 8)
        return [bytes(buf)]

    def _truncate(self) -> list[bytes]:
        buf = self.stream.pack(self._valid())
        return [buf[: self.rng.randrange(1, len(buf))]]

    def _bad_crc(self) -> list[bytes]:
        buf = bytearray(self.stream.pack(self._valid()))
        buf[-2 - self.rng.randrange(2)] ^= self.rng.randrange(1, 256)
        return [bytes(buf)]

    def _unknown_id(self) -> list[bytes]:
        r = self.rng
        msgid = r.choice(self._unknown_ids) if r.random() < 0.5 else r.randrange(2**16, 2**24)
        payload = bytes(r.randrange(256) for _ in range(r.randrange(1, 64)))
        header = bytes([0xFD, len(payload), 0, 0, r.randrange(256), 1, 1, msgid & 0xFF, (msgid >> 8) & 0xFF,
                        msgid >> 16])
        return [header + payload + bytes([r.randrange(256), r.randrange(256)])]

    def _field_values(self) -> list[bytes]:
        return [self._with_fields(self._valid(), floats_only=False)]

    def _nonfinite(self) -> list[bytes]:
        kind = self.rng.choice(("HIGHRES_IMU", "ATTITUDE", "SIMSTATE", "PARAM_VALUE"))
        return [self._with_fields(self._valid(kind), floats_only=True)]

    def _zero_dt(self) -> list[bytes]:
        return [self._timed(self.stream.t - STEP_S)]  # the last valid step's time again

    def _negative_dt(self) -> list[bytes]:
        return [self._timed(self.stream.t - STEP_S - self.rng.uniform(0.001, 0.9))]

    def _time_back(self) -> list[bytes]:
        t = self.stream.t
        return [self._timed(self.rng.choice((0.0, 1e-6, self.rng.uniform(0.0, t), t - self.rng.uniform(1.0, 50.0))))]

    def _time_forward(self) -> list[bytes]:
        return [self._timed(self.stream.t + self.rng.choice((self.rng.uniform(0.02, 1.0), self.rng.uniform(1.0, 1e5),
                                                             4.29e6)))]

    def _duplicate(self) -> list[bytes]:
        return [self.recent[-1]] if self.recent else self._random_bytes()

    def _reorder(self) -> list[bytes]:
        """A valid frame arriving late, behind newer ones (out of order)."""
        if len(self.recent) < 2:
            return self._random_bytes()
        return [self.recent[-self.rng.randint(2, len(self.recent))]]

    def _foreign_source(self) -> list[bytes]:
        tx = self.stream.tx
        saved = tx.srcSystem, tx.srcComponent
        tx.srcSystem, tx.srcComponent = self.rng.choice(((self.rng.randint(2, 255), 1), (1, self.rng.randint(2, 255)),
                                                         (1, 0), (255, 190)))
        try:
            kind = self.rng.choice(TARGETS[:-3] + (self.stream.imu_kind,) * 3)
            return [self.stream.pack(self._valid(kind))]
        finally:
            tx.srcSystem, tx.srcComponent = saved

    def _concat(self) -> list[bytes]:
        parts = [self.frame()[1][0] for _ in range(self.rng.randint(2, 4))]
        return [b"".join(parts)]

    def _split(self) -> list[bytes]:
        buf = self.stream.pack(self._valid())
        cut = self.rng.randrange(1, len(buf))
        return [buf[:cut], buf[cut:]]

    def _mavlink1(self) -> list[bytes]:
        kind = self.rng.choice([k for k in TARGETS if getattr(m, f"MAVLINK_MSG_ID_{k}") < 256])
        return [self.stream.pack(self._valid(kind), mavlink1=True)]
