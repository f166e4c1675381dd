"""Output encoders: the filter's estimate -> GPS_INPUT, HIL_GPS, ODOMETRY, STATUSTEXT.

Frames and units: the estimate is ENU metres relative to the origin on the UTM grid, heading theta on the grid
(ENU rad). `Origin` maps it to WGS84 (lat/lon degE7 on the wire) and turns grid headings into true ones
(true ENU heading = grid heading - meridian convergence). NED yaw psi = pi/2 - theta_true; GPS_INPUT.yaw is
cdeg in 1..36000 (36000 = north; 0 means "no yaw" and is never sent as a heading). Every field is guarded:
nothing non-finite reaches the wire.

HDOP: there are no satellites, so HDOP is derived from the honest 1-sigma horizontal accuracy:
HDOP = horiz_accuracy / hdop_uere_m clipped to [hdop_min, 99.99]. With the default UERE of 2 m, EKF3's
gates (HDOP <= 2.5, accuracy <= 5 m) open and close together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from taco_mav.config import OutputConfig, frd_fwd_left
from taco_mav.core.search import body_to_world
from taco_mav.core.types import Estimate
from taco_mav.geo import UtmProjector, gps_week_ms, utm_epsg_for


def mavlink_dialect() -> Any:
    """The ardupilotmega MAVLink 2 dialect module (constants and message classes)."""
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega

_m = mavlink_dialect()
GPS_FIX_NONE = _m.GPS_FIX_TYPE_NO_FIX  # 1
GPS_FIX_3D = _m.GPS_FIX_TYPE_3D_FIX  # 3
# Fields we do not provide: vertical velocity, vertical accuracy, VDOP.
GPS_INPUT_IGNORE = (_m.GPS_INPUT_IGNORE_FLAG_VEL_VERT | _m.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY
                    | _m.GPS_INPUT_IGNORE_FLAG_VDOP)
MAV_FRAME_LOCAL_NED = _m.MAV_FRAME_LOCAL_NED
MAV_FRAME_BODY_FRD = _m.MAV_FRAME_BODY_FRD
MAV_ESTIMATOR_TYPE_VIO = _m.MAV_ESTIMATOR_TYPE_VIO


@dataclass(frozen=True)
class Origin:
    """The start-up fix: lat, lon degrees WGS84, alt metres AMSL; its UTM zone, UTM position (2,) metres and the
    meridian convergence there, radians (grid heading = true heading + convergence)."""

    lat: float
    lon: float
    alt: float
    projector: UtmProjector
    utm: np.ndarray
    convergence: float

    @classmethod
    def from_latlon(cls, lat: float, lon: float, alt: float, epsg: int | None = None) -> "Origin":
        proj = UtmProjector(epsg if epsg is not None else utm_epsg_for(lat, lon))
        e, n = proj.to_utm(lat, lon)
        return cls(float(lat), float(lon), float(alt), proj, np.array([e, n]), float(proj.grid_convergence(lat, lon)))

    def xy(self, lat: float, lon: float) -> np.ndarray:
        """ENU metres relative to the origin (on its UTM grid) of a WGS84 point (degrees); the inverse of
        `latlon`."""
        e, n = self.projector.to_utm(lat, lon)
        return np.array([float(e), float(n)]) - self.utm

    def latlon(self, xy: np.ndarray) -> tuple[float, float]:
        """WGS84 degrees of an ENU point (metres relative to the origin)."""
        lat, lon = self.projector.to_latlon(self.utm[0] + float(xy[0]), self.utm[1] + float(xy[1]))
        return float(lat), float(lon)


@dataclass(frozen=True)
class NavSolution:
    """What every output is built from. lat/lon degrees; alt m AMSL; x_n/y_e: NED metres from the origin;
    vn/ve: m/s true north/east; yaw_ned: true heading rad (0 = north, CW); sigma_h: 1-sigma horizontal m;
    cov_ne: 2x2 NED position covariance m^2; speed_acc m/s; fix_type GPS_FIX_TYPE; t_autopilot s."""

    t_autopilot: float
    lat: float
    lon: float
    alt: float
    x_n: float
    y_e: float
    vn: float
    ve: float
    speed: float
    yaw_ned: float
    sigma_h: float
    cov_ne: np.ndarray
    speed_acc: float
    fix_type: int


def _f(value: float, fallback: float) -> float:
    return float(value) if math.isfinite(value) else float(fallback)


def antenna_point(xy: np.ndarray, theta: float, antenna_frd_m: tuple[float, float, float]) -> np.ndarray:
    """The autopilot's antenna point, ENU metres: the estimate's reference point `xy` plus the antenna's body
    offset (FRD [x forward, y right, z down] metres; its horizontal part as (forward, left), `frd_fwd_left`)
    rotated by the grid heading theta (ENU rad)."""
    return np.asarray(xy, dtype=float) + body_to_world(theta, np.array(frd_fwd_left(antenna_frd_m)))


def solution(est: Estimate, origin: Origin, cfg: OutputConfig, healthy: bool) -> NavSolution:
    """Build a NavSolution from an estimate; any non-finite part makes the solution unhealthy (fix_type 1) with
    the origin's position and a 1 km accuracy, so nothing non-finite is ever encoded.

    The estimate is the vehicle reference point; the solution is the point the autopilot expects,
    cfg.antenna_frd_m from it (`antenna_point`; altitude = origin altitude - z): the one place where every output
    (GPS_INPUT, HIL_GPS, ODOMETRY) gets its position."""
    sigma = est.sigma_h if np.all(np.isfinite(est.cov_xy)) else float("nan")
    xy = np.asarray(est.xy, dtype=float)
    ok = bool(np.all(np.isfinite(xy)) and math.isfinite(sigma) and math.isfinite(est.theta) and math.isfinite(est.speed))
    if ok:
        xy = antenna_point(xy, float(est.theta), cfg.antenna_frd_m)
        try:
            lat, lon = origin.latlon(xy)
        except Exception:  # noqa: BLE001 - a projection failure must degrade, never crash the output
            ok = False
    if not ok:
        xy, lat, lon, sigma = np.zeros(2), origin.lat, origin.lon, 1000.0
    theta_true = _f(est.theta, 0.0) - origin.convergence
    speed = _f(est.speed, 0.0) if ok else 0.0
    ve, vn = speed * math.cos(theta_true), speed * math.sin(theta_true)
    yaw = math.remainder(math.pi / 2.0 - theta_true, 2.0 * math.pi)
    cov = np.asarray(est.cov_xy, dtype=float) if ok else np.diag([sigma**2, sigma**2])
    cov_ne = np.array([[cov[1, 1], cov[0, 1]], [cov[0, 1], cov[0, 0]]])
    # the filter's own speed 1-sigma where it has one (taco+): on the IMU alone (a camera outage) it grows, and an
    # autopilot told 0.3 m/s steers by a drifting speed (SITL: the rover at 4.4 m/s for a 3 m/s mission)
    sigma_v = _f(est.sigma_speed, 0.0) if ok else 0.0
    speed_acc = max(cfg.speed_accuracy_floor_mps, cfg.speed_accuracy_fraction * abs(speed), sigma_v)
    alt = origin.alt - float(cfg.antenna_frd_m[2])
    return NavSolution(_f(est.t, 0.0), lat, lon, alt, float(xy[1]), float(xy[0]), vn, ve, speed, yaw,
                       float(sigma), cov_ne, speed_acc, GPS_FIX_3D if (ok and healthy) else GPS_FIX_NONE)


def hdop_from_accuracy(sigma_h: float, uere_m: float, hdop_min: float) -> float:
    """HDOP from the 1-sigma horizontal accuracy (see the module docstring)."""
    if not math.isfinite(sigma_h):
        return 99.99
    return float(min(max(sigma_h / uere_m, hdop_min), 99.99))


def yaw_cdeg(yaw_ned: float) -> int:
    """True NED yaw, rad -> GPS_INPUT.yaw cdeg in 1..36000 (north = 36000; 0 is reserved for 'unknown')."""
    if not math.isfinite(yaw_ned):
        return 0
    cdeg = int(round(math.degrees(yaw_ned) * 100.0)) % 36000
    return 36000 if cdeg == 0 else cdeg


def _degE7(deg: float) -> int:
    return int(round(deg * 1e7))


def gps_input(mav: Any, sol: NavSolution, cfg: OutputConfig, unix_time_s: float) -> Any:
    """GPS_INPUT (ArduPilot GPS1_TYPE=14). unix_time_s: UTC now (GPS week/ms = UTC + cfg.leap_seconds)."""
    week, week_ms = gps_week_ms(unix_time_s, cfg.leap_seconds) if math.isfinite(unix_time_s) and unix_time_s > 0 else (0, 0)
    hacc = min(_f(sol.sigma_h, 1000.0), 1000.0)
    hdop = hdop_from_accuracy(hacc, cfg.hdop_uere_m, cfg.hdop_min)
    yaw = yaw_cdeg(sol.yaw_ned) if cfg.send_yaw else 0
    return mav.gps_input_encode(
        int(unix_time_s * 1e6) if unix_time_s > 0 else 0, cfg.gps_id, GPS_INPUT_IGNORE, week_ms, week, sol.fix_type,
        _degE7(sol.lat), _degE7(sol.lon), _f(sol.alt, 0.0), hdop, hdop, _f(sol.vn, 0.0), _f(sol.ve, 0.0), 0.0,
        _f(sol.speed_acc, 1.0), hacc, 0.0, cfg.satellites_visible, yaw)


UNKNOWN_U16 = 65535  # HIL_GPS eph/epv/cog "unknown"
MOVING_MPS = 0.2  # below this speed the course over ground is sent as unknown


def _cm_u16(metres: float) -> int:
    """Metres -> cm for a uint16 field, never the 65535 'unknown' value."""
    return int(min(max(round(_f(metres, 655.34) * 100.0), 0), UNKNOWN_U16 - 1))


def hil_gps(mav: Any, sol: NavSolution, cfg: OutputConfig, unix_time_s: float) -> Any:
    """HIL_GPS (PX4: taken as a GNSS receiver when MAV_USEHILGPS is 1 and the sender has PX4's own sysid).
    PX4 reads eph/epv as the 1-sigma horizontal/vertical accuracy in cm (EKF2_REQ_EPH / _EPV gate them), marks
    vn/ve/vd valid whatever is sent (so they are ours: true north/east m/s, vd 0 on the ground) and stamps the
    message on arrival. time_usec: UTC, us; alt: mm AMSL; cog: true course cdeg, unknown below MOVING_MPS; yaw:
    our true heading when cfg.send_yaw (PX4's handler ignores it today)."""
    cog = yaw_cdeg(sol.yaw_ned) % 36000 if abs(_f(sol.speed, 0.0)) >= MOVING_MPS else UNKNOWN_U16
    vn, ve = (int(round(max(-32767.0, min(32767.0, _f(v, 0.0) * 100.0)))) for v in (sol.vn, sol.ve))
    return mav.hil_gps_encode(
        int(unix_time_s * 1e6) if math.isfinite(unix_time_s) and unix_time_s > 0 else 0, sol.fix_type,
        _degE7(sol.lat), _degE7(sol.lon), int(round(_f(sol.alt, 0.0) * 1000.0)), _cm_u16(sol.sigma_h),
        _cm_u16(cfg.vertical_accuracy_m), _cm_u16(abs(_f(sol.speed, 0.0))), vn, ve, 0, cog, cfg.satellites_visible,
        cfg.gps_id, yaw_cdeg(sol.yaw_ned) if cfg.send_yaw else 0)


def _quat(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]


def odometry(mav: Any, sol: NavSolution, cfg: OutputConfig, roll: float, pitch: float, gyro_frd: tuple[float, float, float],
             yaw_sigma_rad: float, reset_counter: int, t_sender: float | None = None) -> Any:
    """ODOMETRY: time_usec the estimate's time on the sender's clock, s (`t_sender`; default the autopilot clock:
    PX4 maps a companion's stamps through TIMESYNC, ArduPilot learns any constant offset), position in a local
    NED frame about the origin (z = 0: flat ground), attitude from the latest
    ATTITUDE roll/pitch and our yaw, velocity in body FRD (forward speed), rates from the IMU. Covariances are
    the 21-entry upper triangles (x, y, z, roll, pitch, yaw); z takes the horizontal variance (flat-ground
    assumption), roll/pitch 0.01 rad^2."""
    c = sol.cov_ne
    var_h = _f(sol.sigma_h, 1000.0) ** 2
    pose = [0.0] * 21
    pose[0], pose[1], pose[6] = _f(c[0, 0], var_h), _f(c[0, 1], 0.0), _f(c[1, 1], var_h)
    pose[11], pose[15], pose[18], pose[20] = var_h, 0.01, 0.01, yaw_sigma_rad**2
    vel = [0.0] * 21
    sa2 = _f(sol.speed_acc, 1.0) ** 2
    vel[0], vel[6], vel[11], vel[15], vel[18], vel[20] = sa2, sa2, sa2, 0.01, 0.01, 0.01
    q = _quat(_f(roll, 0.0), _f(pitch, 0.0), _f(sol.yaw_ned, 0.0))
    quality = -1 if sol.fix_type != GPS_FIX_3D else max(1, min(100, int(round(100.0 * (1.0 - sol.sigma_h / cfg.degrade_accuracy_m)))))
    g = [_f(v, 0.0) for v in gyro_frd]
    return mav.odometry_encode(
        int(max(_f(sol.t_autopilot if t_sender is None else t_sender, 0.0), 0.0) * 1e6), MAV_FRAME_LOCAL_NED,
        MAV_FRAME_BODY_FRD, _f(sol.x_n, 0.0), _f(sol.y_e, 0.0),
        0.0, q, _f(sol.speed, 0.0), 0.0, 0.0, g[0], g[1], g[2], pose, vel, reset_counter & 0xFF, MAV_ESTIMATOR_TYPE_VIO,
        quality)


def named_value_float(mav: Any, time_boot_ms: int, name: str, value: float) -> Any:
    """NAMED_VALUE_FLOAT (ground-station health, gcs.py): name cut to the field's 10 characters, a non-finite
    value sent as -1, time_boot_ms the autopilot's clock (ms, 0 when unknown)."""
    v = float(value) if math.isfinite(value) else -1.0
    return mav.named_value_float_encode(max(0, min(int(time_boot_ms), 2**32 - 1)), name.encode("ascii")[:10], v)


def statustext(mav: Any, severity: int, text: str) -> Any:
    """STATUSTEXT, text truncated to the field's 50 bytes (prefixed 'TACO: ')."""
    raw = f"TACO: {text}".encode("ascii", "replace")[:50]
    return mav.statustext_encode(severity, raw)
