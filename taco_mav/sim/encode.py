"""MAVLink messages an ArduPilot rover sends, built from one drive sample (ardupilotmega dialect).

Scaling follows ArduPilot's GCS_MAVLink: RAW_IMU / SCALED_IMU acceleration in mG (a / 9.80665 * 1000, so a
level vehicle at rest reads zacc = -1000), gyro in mrad/s, both body FRD and clipped to int16; HIGHRES_IMU
in m/s^2 and rad/s; ATTITUDE NED radians with yaw wrapped to [-pi, pi); GPS_RAW_INT lat/lon degE7, alt mm,
vel cm/s, cog cdeg (0..35999, 0 = north), eph/epv = DOP * 100, h_acc mm; SIMSTATE true pose (lat/lng degE7,
yaw radians NED). `boot_s` is the autopilot's time since boot, seconds; `utc_s` a UTC unix time, seconds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from taco_mav.sim.source import SimDrive

if TYPE_CHECKING:
    from taco_mav.sim.receiver import GnssState

__all__ = ["G", "MG_PER_MPS2", "ardupilot_imu_ints", "attitude", "gps_global_origin", "gps_raw_int", "heartbeat",
           "highres_imu", "home_position", "raw_imu", "scaled_imu", "simstate", "system_time"]

G = 9.80665
MG_PER_MPS2 = 1000.0 / G

# MAVLink enum values used here (common.xml), named to keep the builders readable.
MAV_TYPE_GROUND_ROVER = 10
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_STATE_ACTIVE = 4
GPS_FIX_TYPE_NO_FIX = 1
GPS_FIX_TYPE_3D_FIX = 3
ROVER_MODE_AUTO = 10


def _i16(v: float) -> int:
    return int(np.clip(round(v), -32768, 32767))


def _deg_e7(deg: float) -> int:
    return int(round(deg * 1e7))


def ardupilot_imu_ints(drive: SimDrive, i: int) -> tuple[int, int, int, int, int, int]:
    """(xacc, yacc, zacc mG, xgyro, ygyro, zgyro mrad/s) of sample i, rounded and clipped as ArduPilot does."""
    a = drive.accel_frd[i] * MG_PER_MPS2
    g = drive.gyro_frd[i] * 1000.0
    return _i16(a[0]), _i16(a[1]), _i16(a[2]), _i16(g[0]), _i16(g[1]), _i16(g[2])


def heartbeat(mav: Any) -> Any:
    """HEARTBEAT of an armed ArduPilot rover in AUTO."""
    return mav.heartbeat_encode(MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_ARDUPILOTMEGA,
                                MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | 128, ROVER_MODE_AUTO, MAV_STATE_ACTIVE)


def raw_imu(mav: Any, drive: SimDrive, i: int, boot_s: float) -> Any:
    """RAW_IMU of sample i stamped `boot_s` (time_usec = microseconds since boot)."""
    ax, ay, az, gx, gy, gz = ardupilot_imu_ints(drive, i)
    return mav.raw_imu_encode(int(round(boot_s * 1e6)), ax, ay, az, gx, gy, gz, 0, 0, 0, 0, 0)


def scaled_imu(mav: Any, drive: SimDrive, i: int, boot_s: float) -> Any:
    """SCALED_IMU of sample i (same scaling as RAW_IMU, time_boot_ms)."""
    ax, ay, az, gx, gy, gz = ardupilot_imu_ints(drive, i)
    return mav.scaled_imu_encode(int(round(boot_s * 1e3)), ax, ay, az, gx, gy, gz, 0, 0, 0)


def highres_imu(mav: Any, drive: SimDrive, i: int, boot_s: float) -> Any:
    """HIGHRES_IMU of sample i: FRD m/s^2 and rad/s; fields_updated marks acc and gyro (bits 0-5)."""
    a, g = drive.accel_frd[i], drive.gyro_frd[i]
    return mav.highres_imu_encode(int(round(boot_s * 1e6)), float(a[0]), float(a[1]), float(a[2]),
                                  float(g[0]), float(g[1]), float(g[2]), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                                  0x3F)


def attitude(mav: Any, drive: SimDrive, i: int, boot_s: float) -> Any:
    """ATTITUDE of sample i: NED roll/pitch/yaw rad and FRD body rates rad/s."""
    r, p, y = (float(v) for v in drive.rpy_ned[i])
    g = drive.gyro_frd[i]
    y = math.remainder(y, 2.0 * math.pi)
    return mav.attitude_encode(int(round(boot_s * 1e3)), r, p, y, float(g[0]), float(g[1]), float(g[2]))


def system_time(mav: Any, utc_s: float, boot_s: float) -> Any:
    """SYSTEM_TIME: UTC unix time in microseconds and time since boot in milliseconds."""
    return mav.system_time_encode(int(round(utc_s * 1e6)), int(round(boot_s * 1e3)) & 0xFFFFFFFF)


def gps_raw_int(mav: Any, drive: SimDrive, i: int, boot_s: float, fix: bool, satellites: int = 10,
                hdop: float = 0.8, h_acc_m: float = 0.5) -> Any:
    """GPS_RAW_INT of sample i: a 3D fix from the OXTS reading, or NO_FIX (position and velocity zero)."""
    stamp = int(round(boot_s * 1e6))
    if not fix:
        return mav.gps_raw_int_encode(stamp, GPS_FIX_TYPE_NO_FIX, 0, 0, 0, 65535, 65535, 65535, 65535, 0)
    vn, ve = float(drive.vn[i]), float(drive.ve[i])
    cog = int(round(math.degrees(math.atan2(ve, vn)) * 100.0)) % 36000
    return mav.gps_raw_int_encode(
        stamp, GPS_FIX_TYPE_3D_FIX, _deg_e7(float(drive.lat[i])), _deg_e7(float(drive.lon[i])),
        int(round(float(drive.alt[i]) * 1000.0)), int(round(hdop * 100)), int(round(hdop * 150)),
        int(round(math.hypot(vn, ve) * 100.0)), cog, satellites,
        int(round(float(drive.alt[i]) * 1000.0)), int(round(h_acc_m * 1000)), int(round(h_acc_m * 1500)), 100, 0, 0)


def global_position_int(mav: Any, s: GnssState | None, boot_s: float) -> Any:
    """GLOBAL_POSITION_INT: the autopilot's own estimate `s` (None: it has none yet, lat = lon = 0), time since
    boot ms, lat/lon degE7, alt mm, velocity NED cm/s, heading cdeg (UINT16_MAX unknown)."""
    ms = int(round(boot_s * 1e3)) & 0xFFFFFFFF
    if s is None:
        return mav.global_position_int_encode(ms, 0, 0, 0, 0, 0, 0, 0, 65535)
    return mav.global_position_int_encode(ms, _deg_e7(s.lat), _deg_e7(s.lon), int(round(s.alt * 1000.0)), 0,
                                          _i16(s.vn * 100.0), _i16(s.ve * 100.0), 0, 65535)


def home_position(mav: Any, lat: float, lon: float, alt: float, boot_s: float) -> Any:
    """HOME_POSITION at lat, lon (degrees) and alt (m AMSL): degE7, mm; local position and approach zero."""
    return mav.home_position_encode(_deg_e7(lat), _deg_e7(lon), int(round(alt * 1000.0)), 0.0, 0.0, 0.0,
                                    [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(round(boot_s * 1e6)))


def gps_global_origin(mav: Any, lat: float, lon: float, alt: float, boot_s: float) -> Any:
    """GPS_GLOBAL_ORIGIN (the EKF origin) at lat, lon (degrees) and alt (m AMSL): degE7, mm."""
    return mav.gps_global_origin_encode(_deg_e7(lat), _deg_e7(lon), int(round(alt * 1000.0)), int(round(boot_s * 1e6)))


def simstate(mav: Any, drive: SimDrive, i: int) -> Any:
    """SIMSTATE of sample i: the TRUE pose (lat/lng degE7, yaw rad NED), IMU attitude/accel/gyro alongside."""
    r, p, _ = (float(v) for v in drive.rpy_ned[i])
    a, g = drive.accel_frd[i], drive.gyro_frd[i]
    return mav.simstate_encode(r, p, float(drive.true_yaw_ned[i]), float(a[0]), float(a[1]), float(a[2]),
                               float(g[0]), float(g[1]), float(g[2]), _deg_e7(float(drive.true_lat[i])),
                               _deg_e7(float(drive.true_lon[i])))
