"""Input decoders: MAVLink messages -> validated readings in SI units, with rejected inputs counted by reason.

Frames and units (DESIGN.md):
- RAW_IMU / SCALED_IMU / SCALED_IMU2 / SCALED_IMU3: body FRD, acceleration in mG (a level vehicle at rest reads
  zacc = -1000 mG -> -9.80665 m/s^2), gyro in mrad/s -> rad/s. Time: RAW_IMU time_usec, SCALED_IMU* time_boot_ms.
- HIGHRES_IMU: body FRD, m/s^2 and rad/s; time_usec.
- ATTITUDE: roll, pitch, yaw radians, NED (yaw 0 = north, CW); rollspeed/pitchspeed/yawspeed FRD body rad/s;
  time_boot_ms.
- GPS_RAW_INT (GPS instance 1) / GPS2_RAW (instance 2): lat/lon degE7, alt mm AMSL, eph HDOP x 100, vel cm/s,
  cog cdeg (65535 = unknown for all three), h_acc mm and vel_acc mm/s (0 = not reported).
- GPS_GLOBAL_ORIGIN / HOME_POSITION: latitude/longitude degE7, altitude mm AMSL.
- SIMSTATE (ArduPilot SITL) / HIL_STATE_QUATERNION (PX4 SIH, when asked for): lat/lng (lon) degE7, yaw radians
  NED or the body-to-NED attitude quaternion [w, x, y, z] (the simulator's true pose).
- WHEEL_DISTANCE (id 9000): time_usec (ArduPilot: 1000 x its millis() at sending), count wheels, distance[16]
  cumulative metres per wheel (the first `count` used; forward positive).
All times come out as autopilot seconds.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

G0 = 9.80665  # m/s^2 per g, as ArduPilot scales RAW_IMU
MAX_ACCEL = 16.0 * G0  # m/s^2: beyond a 16 g accelerometer's range
MAX_GYRO = math.radians(2000.0)  # rad/s: beyond a 2000 deg/s gyro's range
MAX_ATTITUDE_CARRY_S = 0.2  # s: the furthest an ATTITUDE is carried at its rates to an IMU sample's time

IMU_MESSAGES = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
UTM_LAT_MIN, UTM_LAT_MAX = -80.0, 84.0  # degrees: the daemon works on a UTM grid (geo.utm_epsg_for)
GNSS_MESSAGES = {"GPS_RAW_INT": 1, "GPS2_RAW": 2}  # message -> GPS instance it reports (1 = GPS1), as ArduPilot
ORIGIN_MESSAGES = ("GPS_GLOBAL_ORIGIN", "HOME_POSITION")
POSITION_MESSAGE = "GLOBAL_POSITION_INT"  # the autopilot's own estimate (EKF): where a restarted daemon starts
POSE_MESSAGES = ("SIMSTATE", "HIL_STATE_QUATERNION")  # a simulator's true pose: ArduPilot SITL's, PX4 SIH's
WHEEL_MESSAGE = "WHEEL_DISTANCE"  # the wheel encoders' cumulative distances
# ArduPilot's parameters of the first two wheels' lateral positions (AP_WheelEncoder: body FRD y, metres)
WHEEL_POS_PARAMS = ("WENC_POS_Y", "WENC2_POS_Y")
MAX_WHEELS = 16  # WHEEL_DISTANCE.distance's length
MAX_WHEEL_DISTANCE_M = 1.0e7  # |cumulative distance| beyond this (10 000 km) is garbage
UNKNOWN_U16 = 65535
MAX_ALT_M = 20_000.0  # |altitude| beyond this (m AMSL) is not a ground vehicle's
MAX_SPEED_MPS = 150.0  # ground speed beyond this is not a ground vehicle's
MAX_H_ACC_M = 1000.0  # a "3D fix" claiming worse than this is garbage
MAX_FIX_TYPE = 8  # GPS_FIX_TYPE_PPP


@dataclass(frozen=True, slots=True)
class ImuReading:
    """t: autopilot s; accel_frd m/s^2 (gravity included); gyro_frd rad/s; source: the message name."""

    t: float
    accel_frd: tuple[float, float, float]
    gyro_frd: tuple[float, float, float]
    source: str


@dataclass(frozen=True, slots=True)
class AttitudeReading:
    """t: autopilot s; roll, pitch, yaw: NED radians (ZYX Euler); euler_rates: d(roll, pitch, yaw)/dt in rad/s,
    from the message's FRD body rates (zero when they were unusable)."""

    t: float
    roll: float
    pitch: float
    yaw: float
    euler_rates: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def at(self, t: float) -> AttitudeReading:
        """This attitude carried to autopilot time `t` (s) at its Euler rates, so that an IMU sample is paired
        with the attitude of its own time rather than the last one received. Unchanged when `t` is more than
        MAX_ATTITUDE_CARRY_S away (a stalled attitude stream or another clock: not extrapolated)."""
        dt = t - self.t
        if abs(dt) > MAX_ATTITUDE_CARRY_S:
            return self
        dr, dp, dy = self.euler_rates
        return AttitudeReading(self.t + dt, self.roll + dr * dt, self.pitch + dp * dt,
                               math.remainder(self.yaw + dy * dt, 2 * math.pi), self.euler_rates)


def euler_rates(roll: float, pitch: float, p: float, q: float, r: float) -> tuple[float, float, float]:
    """ZYX Euler angle rates (roll, pitch, yaw) in rad/s from FRD body rates p, q, r (rad/s) at roll, pitch (rad);
    zeros near pitch +-90 deg, where yaw and roll are not defined."""
    c_p = math.cos(pitch)
    if abs(c_p) < 0.1:
        return 0.0, 0.0, 0.0
    s_r, c_r = math.sin(roll), math.cos(roll)
    yaw_rate = (q * s_r + r * c_r) / c_p
    return p + yaw_rate * math.sin(pitch), q * c_r - r * s_r, yaw_rate


@dataclass(frozen=True, slots=True)
class GnssReading:
    """t: autopilot s (the message's time_usec); lat, lon: degrees WGS84; alt: metres AMSL; speed: m/s over
    ground (0 when unknown, see speed_known); course_ned: radians (0 = north, CW) or None when unknown;
    fix_type: GPS_FIX_TYPE; satellites: count (255 = unknown); instance: 1 = GPS1 (GPS_RAW_INT), 2 = GPS2
    (GPS2_RAW); h_acc_m: 1-sigma horizontal accuracy m, vel_acc_mps: 1-sigma speed accuracy m/s, hdop: HDOP;
    each None when the receiver did not report it."""

    t: float
    lat: float
    lon: float
    alt: float
    speed: float
    course_ned: float | None
    fix_type: int
    satellites: int
    instance: int = 1
    h_acc_m: float | None = None
    vel_acc_mps: float | None = None
    hdop: float | None = None
    speed_known: bool = True


@dataclass(frozen=True, slots=True)
class OriginReading:
    """A position the autopilot offers as the start: GPS_GLOBAL_ORIGIN (the EKF origin) or HOME_POSITION.
    lat, lon: degrees WGS84; alt: metres AMSL; source: the message name."""

    lat: float
    lon: float
    alt: float
    source: str


@dataclass(frozen=True, slots=True)
class AutopilotPosition:
    """The autopilot's own estimate of where the vehicle is (GLOBAL_POSITION_INT): t autopilot s (time_boot_ms);
    lat, lon degrees WGS84; alt metres AMSL; speed m/s over ground; course_ned radians (0 = north, CW), None
    when the vehicle is still (slower than STILL_MPS: the direction of a near-zero velocity is noise)."""

    t: float
    lat: float
    lon: float
    alt: float
    speed: float
    course_ned: float | None


STILL_MPS = 0.2


@dataclass(frozen=True, slots=True)
class WheelDistanceReading:
    """t: autopilot s (time_usec); distances: cumulative metres per wheel, forward positive (count of them)."""

    t: float
    distances: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class SimPose:
    """The simulator's true pose: lat, lon degrees; yaw NED radians (true north)."""

    lat: float
    lon: float
    yaw: float


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _on_utm_grid(lat: float, lon: float) -> bool:
    """True for a position the daemon can project: UTM's latitude band, longitude in [-180, 180] degrees."""
    return UTM_LAT_MIN <= lat <= UTM_LAT_MAX and -180.0 <= lon <= 180.0


class Decoders:
    """Stateless conversions plus `rejected`, a Counter of "<MESSAGE>:<reason>" for every refused input."""

    def __init__(self) -> None:
        self.rejected: Counter[str] = Counter()

    def reject(self, msg_type: str, reason: str) -> None:
        """Count one refused input as "<msg_type>:<reason>"."""
        self.rejected[f"{msg_type}:{reason}"] += 1

    def imu(self, msg: Any) -> ImuReading | None:
        """Any of IMU_MESSAGES -> ImuReading, or None (counted) when implausible."""
        kind = msg.get_type()
        if kind == "HIGHRES_IMU":
            updated = int(msg.fields_updated)
            if updated and (updated & 0x3F) != 0x3F:
                self.reject(kind, "partial")
                return None
            t = msg.time_usec * 1e-6
            acc = (float(msg.xacc), float(msg.yacc), float(msg.zacc))
            gyr = (float(msg.xgyro), float(msg.ygyro), float(msg.zgyro))
        elif kind in ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"):
            if kind == "RAW_IMU":
                t = msg.time_usec * 1e-6
            else:
                t = msg.time_boot_ms * 1e-3
            k_acc, k_gyr = G0 * 1e-3, 1e-3
            acc = (msg.xacc * k_acc, msg.yacc * k_acc, msg.zacc * k_acc)
            gyr = (msg.xgyro * k_gyr, msg.ygyro * k_gyr, msg.zgyro * k_gyr)
        else:
            self.reject(kind, "not_imu")
            return None
        if not _finite(t, *acc, *gyr):
            self.reject(kind, "nonfinite")
            return None
        if t <= 0.0:
            self.reject(kind, "no_time")
            return None
        if max(abs(a) for a in acc) > MAX_ACCEL:
            self.reject(kind, "accel_range")
            return None
        if max(abs(g) for g in gyr) > MAX_GYRO:
            self.reject(kind, "gyro_range")
            return None
        if acc == (0.0, 0.0, 0.0):
            self.reject(kind, "all_zero")  # an IMU that is not delivering (every axis exactly zero)
            return None
        return ImuReading(t, acc, gyr, kind)

    def attitude(self, msg: Any) -> AttitudeReading | None:
        """ATTITUDE -> AttitudeReading (NED radians) or None (counted)."""
        r, p, y = float(msg.roll), float(msg.pitch), float(msg.yaw)
        if not _finite(r, p, y):
            self.reject("ATTITUDE", "nonfinite")
            return None
        if abs(r) > math.pi + 1e-3 or abs(p) > math.pi / 2 + 1e-3 or not -math.pi - 1e-3 <= y <= 2 * math.pi + 1e-3:
            self.reject("ATTITUDE", "range")
            return None
        body = (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed))
        rates = (0.0, 0.0, 0.0)
        if _finite(*body) and max(abs(w) for w in body) <= MAX_GYRO:
            rates = euler_rates(r, p, *body)
        else:
            self.reject("ATTITUDE", "rates")  # the angles are still used, without carrying them in time
        return AttitudeReading(msg.time_boot_ms * 1e-3, r, p, math.remainder(y, 2 * math.pi), rates)

    def gnss(self, msg: Any) -> GnssReading | None:
        """GPS_RAW_INT or GPS2_RAW with a 3D fix (fix_type >= 3) inside UTM's latitude band -> GnssReading, or
        None (counted as "<MESSAGE>:<reason>"). Values no ground vehicle's receiver reports (altitude, speed,
        course, accuracy, fix type out of range) refuse the whole reading."""
        kind = msg.get_type()
        fix = int(msg.fix_type)
        if fix < 3:
            self.reject(kind, "no_3d_fix")
            return None
        if fix > MAX_FIX_TYPE:
            self.reject(kind, "fix_type_range")
            return None
        lat, lon = msg.lat * 1e-7, msg.lon * 1e-7
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0) or (msg.lat == 0 and msg.lon == 0):
            self.reject(kind, "position_range")
            return None
        if not _on_utm_grid(lat, lon):
            self.reject(kind, "outside_utm")  # polar: no UTM zone to work in
            return None
        alt = msg.alt * 1e-3
        if abs(alt) > MAX_ALT_M:
            self.reject(kind, "alt_range")
            return None
        speed_known = int(msg.vel) != UNKNOWN_U16
        speed = msg.vel * 0.01 if speed_known else 0.0
        if speed > MAX_SPEED_MPS:
            self.reject(kind, "speed_range")
            return None
        cog = int(msg.cog)
        if cog != UNKNOWN_U16 and cog > 36000:
            self.reject(kind, "course_range")
            return None
        course = None if cog == UNKNOWN_U16 else math.radians(cog * 0.01)
        h_acc = int(getattr(msg, "h_acc", 0)) * 1e-3 or None  # mm; 0 = not reported
        if h_acc is not None and h_acc > MAX_H_ACC_M:
            self.reject(kind, "accuracy_range")
            return None
        vel_acc = int(getattr(msg, "vel_acc", 0)) * 1e-3 or None  # mm/s; 0 = not reported
        eph = int(msg.eph)
        hdop = eph * 0.01 if 0 < eph < UNKNOWN_U16 else None
        return GnssReading(msg.time_usec * 1e-6, lat, lon, alt, speed, course, fix, int(msg.satellites_visible),
                           GNSS_MESSAGES.get(kind, 1), h_acc, vel_acc, hdop, speed_known)

    def origin(self, msg: Any) -> OriginReading | None:
        """GPS_GLOBAL_ORIGIN or HOME_POSITION -> OriginReading, or None (counted) when unset or out of range."""
        kind = msg.get_type()
        if msg.latitude == 0 and msg.longitude == 0:
            self.reject(kind, "unset")
            return None
        lat, lon, alt = msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0) or abs(alt) > MAX_ALT_M:
            self.reject(kind, "position_range")
            return None
        if not _on_utm_grid(lat, lon):
            self.reject(kind, "outside_utm")
            return None
        return OriginReading(lat, lon, alt, kind)

    def autopilot_position(self, msg: Any) -> AutopilotPosition | None:
        """GLOBAL_POSITION_INT -> AutopilotPosition, or None (counted) while the autopilot has no position
        (lat = lon = 0) or when a value is out of a ground vehicle's range."""
        kind = msg.get_type()
        if msg.lat == 0 and msg.lon == 0:
            self.reject(kind, "unset")
            return None
        lat, lon, alt = msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3
        if not _on_utm_grid(lat, lon) or abs(alt) > MAX_ALT_M:
            self.reject(kind, "position_range")
            return None
        vn, ve = msg.vx * 0.01, msg.vy * 0.01  # cm/s, NED
        speed = math.hypot(vn, ve)
        if speed > MAX_SPEED_MPS:
            self.reject(kind, "speed_range")
            return None
        course = math.atan2(ve, vn) % (2.0 * math.pi) if speed >= STILL_MPS else None
        return AutopilotPosition(msg.time_boot_ms * 1e-3, lat, lon, alt, speed, course)

    def sim_pose(self, msg: Any) -> SimPose | None:
        """SIMSTATE or HIL_STATE_QUATERNION -> the simulator's true pose, or None (counted)."""
        kind = msg.get_type()
        if kind == "SIMSTATE":
            lat_e7, lon_e7, yaw = msg.lat, msg.lng, float(msg.yaw)
        else:
            w, x, y, z = (float(v) for v in msg.attitude_quaternion)
            lat_e7, lon_e7 = msg.lat, msg.lon
            yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)) if _finite(w, x, y, z) else math.nan
        lat, lon = lat_e7 * 1e-7, lon_e7 * 1e-7
        if not _finite(yaw) or not _on_utm_grid(lat, lon) or (lat_e7 == 0 and lon_e7 == 0):
            self.reject(kind, "range")
            return None
        return SimPose(lat, lon, yaw)

    def wheel_distance(self, msg: Any) -> WheelDistanceReading | None:
        """WHEEL_DISTANCE -> the first `count` wheels' cumulative distances, or None (counted) without a time, a
        wheel, or with a non-finite or absurd distance."""
        kind = msg.get_type()
        count = int(msg.count)
        if not 1 <= count <= MAX_WHEELS:
            self.reject(kind, "count")
            return None
        t = int(msg.time_usec) * 1e-6
        if t <= 0.0:
            self.reject(kind, "no_time")
            return None
        d = tuple(float(x) for x in list(msg.distance)[:count])
        if len(d) != count or not _finite(*d) or max(abs(x) for x in d) > MAX_WHEEL_DISTANCE_M:
            self.reject(kind, "range")
            return None
        return WheelDistanceReading(t, d)
