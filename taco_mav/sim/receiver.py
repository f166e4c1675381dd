"""The simulated autopilot's two GPS instances, as ArduPilot reports them (GPS_RAW_INT = GPS1, GPS2_RAW = GPS2).

- `GnssReceiver`: the drive's real receiver. Position = the true pose (SimDrive.true_lat/true_lon) plus white
  noise plus a slowly wandering first-order Gauss-Markov bias (per axis, correlation time `bias_tau_s`; white
  and bias share the variance: sigma_white = sigma / 2, sigma_bias = sigma sqrt(3) / 2), seeded; it reports
  h_acc = sigma (at least 0.5 m). Denial: from `deny_after_s` of drive time NO_FIX (0: never a fix). Spoofing:
  from `spoof_after_s` the fix stays confident (3D, same accuracy) while its position is dragged away at
  `spoof_drift_mps` along the fixed `spoof_bearing_deg` (true, from north, clockwise), after an optional
  `spoof_jump_m`; its velocity carries the drag, as a careful spoofer's would.
- `EchoInstance`: the instance whose GPSn_TYPE is 14 (MAV) reports the companion's last kept GPS_INPUT:
  NO_FIX before the first one.

Units on the wire (`GnssState`): lat/lon degrees, alt m AMSL, vn/ve m/s, hdop, h_acc m, vel_acc m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from taco_mav.geo import UtmProjector
from taco_mav.sim.source import SimDrive

__all__ = ["EchoInstance", "GnssReceiver", "GnssState", "NO_FIX", "gps_message"]

GPS_FIX_TYPE_NO_FIX = 1
GPS_FIX_TYPE_3D_FIX = 3
U16_UNKNOWN = 65535


@dataclass(frozen=True)
class GnssState:
    """What one GPS instance reports now (see the module docstring for units); fix_type GPS_FIX_TYPE."""

    fix_type: int
    lat: float = 0.0
    lon: float = 0.0
    alt: float = 0.0
    vn: float = 0.0
    ve: float = 0.0
    hdop: float | None = None
    h_acc: float | None = None
    vel_acc: float | None = None
    satellites: int = 0


NO_FIX = GnssState(GPS_FIX_TYPE_NO_FIX)


class GnssReceiver:
    """The drive's real receiver (module docstring). `state(i)` is its report at drive sample i."""

    def __init__(self, drive: SimDrive, noise_m: float = 1.0, seed: int = 0, deny_after_s: float = math.inf,
                 spoof_after_s: float | None = None, spoof_drift_mps: float = 0.0, spoof_jump_m: float = 0.0,
                 spoof_bearing_deg: float = 90.0, bias_tau_s: float = 60.0) -> None:
        self.drive, self.noise_m, self.deny_after_s = drive, float(noise_m), float(deny_after_s)
        self.spoof_after_s = spoof_after_s
        n = len(drive)
        rng = np.random.default_rng(seed)
        t = np.asarray(drive.t, dtype=float)
        sw, sb = 0.5 * noise_m, math.sqrt(0.75) * noise_m
        bias = np.zeros((n, 2))
        if n:
            bias[0] = rng.normal(0.0, sb, 2)
        for k in range(1, n):  # exact discretisation of the Gauss-Markov process over each sample step
            phi = math.exp(-(t[k] - t[k - 1]) / bias_tau_s)
            bias[k] = phi * bias[k - 1] + rng.normal(0.0, sb * math.sqrt(max(1.0 - phi * phi, 0.0)), 2)
        offset = rng.normal(0.0, sw, (n, 2)) + bias  # (east, north) m
        vel_spoof = np.zeros((n, 2))
        if spoof_after_s is not None:
            b = math.radians(spoof_bearing_deg)
            direction = np.array([math.sin(b), math.cos(b)])  # (east, north)
            dt = np.clip(t - spoof_after_s, 0.0, None)
            on = t >= spoof_after_s
            offset += on[:, None] * (spoof_jump_m + spoof_drift_mps * dt)[:, None] * direction
            vel_spoof = on[:, None] * spoof_drift_mps * direction
        proj = UtmProjector(drive.utm_epsg)
        e, nn = proj.to_utm(np.asarray(drive.true_lat), np.asarray(drive.true_lon))
        lat, lon = proj.to_latlon(np.asarray(e) + offset[:, 0], np.asarray(nn) + offset[:, 1])
        self.lat, self.lon = np.atleast_1d(lat), np.atleast_1d(lon)
        self.offset = offset
        self.vn = np.asarray(drive.vn, dtype=float) + vel_spoof[:, 1]
        self.ve = np.asarray(drive.ve, dtype=float) + vel_spoof[:, 0]
        self.h_acc = max(self.noise_m, 0.5)

    def has_fix(self, t: float) -> bool:
        """A 3D fix at drive time t (s)?"""
        return t < self.deny_after_s

    def state(self, i: int) -> GnssState:
        t = float(self.drive.t[i])
        if not self.has_fix(t):
            return NO_FIX
        return GnssState(GPS_FIX_TYPE_3D_FIX, float(self.lat[i]), float(self.lon[i]), float(self.drive.alt[i]),
                         float(self.vn[i]), float(self.ve[i]), hdop=0.8, h_acc=self.h_acc, vel_acc=0.3,
                         satellites=10)


class EchoInstance:
    """A GPS instance of type 14: it reports what the companion's last kept GPS_INPUT said."""

    def __init__(self) -> None:
        self.last: GnssState = NO_FIX

    def on_gps_input(self, msg: Any) -> None:
        """A GPS_INPUT the driver kept (the monitor's instance)."""
        flags = int(msg.ignore_flags)
        self.last = GnssState(int(msg.fix_type), msg.lat * 1e-7, msg.lon * 1e-7, float(msg.alt), float(msg.vn),
                              float(msg.ve), hdop=None if flags & 2 else float(msg.hdop),
                              h_acc=None if flags & 64 else float(msg.horiz_accuracy),
                              vel_acc=None if flags & 32 else float(msg.speed_accuracy),
                              satellites=int(msg.satellites_visible))

    def state(self) -> GnssState:
        return self.last


def _u16(v: float | None, scale: float) -> int:
    if v is None or not math.isfinite(v):
        return U16_UNKNOWN
    return int(min(max(round(v * scale), 0), U16_UNKNOWN - 1))


def _u32(v: float | None, scale: float) -> int:
    if v is None or not math.isfinite(v):
        return 0
    return int(min(max(round(v * scale), 0), 2**32 - 1))


def gps_message(mav: Any, instance: int, boot_s: float, s: GnssState) -> Any:
    """GPS_RAW_INT (instance 1) or GPS2_RAW (instance 2) reporting `s`, stamped `boot_s` (autopilot s): lat/lon
    degE7, alt mm, eph HDOP x 100, vel cm/s, cog cdeg (0..35999; 65535 unknown), h_acc mm, vel_acc mm/s."""
    stamp = int(round(boot_s * 1e6))
    fixed = s.fix_type >= GPS_FIX_TYPE_3D_FIX
    lat, lon = (int(round(s.lat * 1e7)), int(round(s.lon * 1e7))) if fixed else (0, 0)
    alt = int(round(s.alt * 1000.0)) if fixed else 0
    speed = math.hypot(s.vn, s.ve)
    vel = _u16(speed, 100.0) if fixed else U16_UNKNOWN
    cog = int(round(math.degrees(math.atan2(s.ve, s.vn)) * 100.0)) % 36000 if fixed else U16_UNKNOWN
    eph = _u16(s.hdop, 100.0) if fixed else U16_UNKNOWN
    epv = _u16(None if s.hdop is None else s.hdop * 1.5, 100.0) if fixed else U16_UNKNOWN
    h_acc, vel_acc = (_u32(s.h_acc, 1000.0), _u32(s.vel_acc, 1000.0)) if fixed else (0, 0)
    v_acc = _u32(None if s.h_acc is None else s.h_acc * 1.5, 1000.0) if fixed else 0
    sats = s.satellites if fixed else 0
    if instance == 1:
        return mav.gps_raw_int_encode(stamp, s.fix_type, lat, lon, alt, eph, epv, vel, cog, sats, alt, h_acc, v_acc,
                                      vel_acc, 0, 0)
    return mav.gps2_raw_encode(stamp, s.fix_type, lat, lon, alt, eph, epv, vel, cog, sats, 0, 0, 0, alt, h_acc, v_acc,
                               vel_acc, 0)
