"""Geodesy and time conventions: UTM <-> WGS84 (pyproj), heading conventions, GPS week and milliseconds.

Frames: the world is UTM easting/northing metres (ENU axes); headings are ENU radians (theta: 0 = east, CCW
positive) unless named `ned` (psi: 0 = north, CW positive, as in MAVLink ATTITUDE). Angles are wrapped to
[-pi, pi). Latitude/longitude are WGS84 degrees. Times are seconds; GPS time = UTC + leap seconds, counted
from the GPS epoch 1980-01-06 00:00:00.
"""

from __future__ import annotations

import calendar
import functools
import math
from typing import overload

import numpy as np
from pyproj import Proj, Transformer

from taco_mav.errors import ConfigError, DataError

__all__ = [
    "GPS_EPOCH_UNIX_S",
    "SECONDS_PER_WEEK",
    "UtmProjector",
    "enu_from_ned_yaw",
    "gps_leap_seconds_at",
    "gps_week_ms",
    "grid_convergence",
    "ned_from_enu_yaw",
    "unix_from_gps_week_ms",
    "utm_epsg_for",
    "wrap_angle",
]

GPS_EPOCH_UNIX_S: int = calendar.timegm((1980, 1, 6, 0, 0, 0))  # 315964800
SECONDS_PER_WEEK: int = 7 * 24 * 3600

# UTC dates from which GPS time ran ahead of UTC by one more second (IERS bulletin C); 18 s since 2017-01-01.
_LEAP_DATES: tuple[tuple[int, int, int], ...] = (
    (1981, 7, 1), (1982, 7, 1), (1983, 7, 1), (1985, 7, 1), (1988, 1, 1), (1990, 1, 1), (1991, 1, 1),
    (1992, 7, 1), (1993, 7, 1), (1994, 7, 1), (1996, 1, 1), (1997, 7, 1), (1999, 1, 1), (2006, 1, 1),
    (2009, 1, 1), (2012, 7, 1), (2015, 7, 1), (2017, 1, 1),
)
_LEAP_UNIX_S: tuple[int, ...] = tuple(calendar.timegm((y, m, d, 0, 0, 0)) for y, m, d in _LEAP_DATES)


# ----------------------------------------------------------------------------------------------- angles

@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: np.ndarray) -> np.ndarray: ...
def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Wrap radians to [-pi, pi); scalars stay Python floats, arrays keep their shape."""
    wrapped = np.mod(np.asarray(a, dtype=np.float64) + math.pi, 2.0 * math.pi) - math.pi
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


@overload
def enu_from_ned_yaw(psi: float) -> float: ...
@overload
def enu_from_ned_yaw(psi: np.ndarray) -> np.ndarray: ...
def enu_from_ned_yaw(psi: float | np.ndarray) -> float | np.ndarray:
    """ENU heading theta (0 = east, CCW) from NED yaw psi (0 = north, CW), radians: theta = pi/2 - psi."""
    return wrap_angle(math.pi / 2.0 - np.asarray(psi, dtype=np.float64))


@overload
def ned_from_enu_yaw(theta: float) -> float: ...
@overload
def ned_from_enu_yaw(theta: np.ndarray) -> np.ndarray: ...
def ned_from_enu_yaw(theta: float | np.ndarray) -> float | np.ndarray:
    """NED yaw psi (0 = north, CW) from ENU heading theta (0 = east, CCW), radians: psi = pi/2 - theta."""
    return wrap_angle(math.pi / 2.0 - np.asarray(theta, dtype=np.float64))


# ------------------------------------------------------------------------------------------------- UTM

def utm_epsg_for(lat: float, lon: float) -> int:
    """EPSG code of the WGS84 UTM zone holding (lat, lon) degrees: 326zz north of the equator, 327zz south.

    Follows the standard zoning, including the widened zone 32V (south-west Norway) and the Svalbard zones
    31X/33X/35X/37X. Raises DataError outside UTM's latitude band [-80, 84] or for non-finite input.
    """
    lat, lon = float(lat), float(lon)
    if not (math.isfinite(lat) and math.isfinite(lon)) or not -80.0 <= lat <= 84.0 or not -180.0 <= lon <= 180.0:
        raise DataError(f"lat {lat}, lon {lon}: outside the UTM domain (lat in [-80, 84], lon in [-180, 180])")
    zone = min(int((lon + 180.0) // 6.0) + 1, 60)
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    elif 72.0 <= lat <= 84.0 and 0.0 <= lon < 42.0:
        zone = 31 if lon < 9.0 else 33 if lon < 21.0 else 35 if lon < 33.0 else 37
    return (32600 if lat >= 0.0 else 32700) + zone


@functools.lru_cache(maxsize=32)
def _transformers(epsg: int) -> tuple[Transformer, Transformer]:
    forward = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    inverse = Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True)
    return forward, inverse


@functools.lru_cache(maxsize=32)
def _proj(epsg: int) -> Proj:
    return Proj(f"EPSG:{epsg}")


def _out(x: np.ndarray) -> float | np.ndarray:
    return float(x) if np.ndim(x) == 0 else x


class UtmProjector:
    """WGS84 degrees <-> one UTM zone's easting/northing metres, vectorised (scalars in, floats out;
    arrays in, arrays of the same shape out). Transformers are built once per zone and shared."""

    def __init__(self, epsg: int) -> None:
        if not (32601 <= epsg <= 32660 or 32701 <= epsg <= 32760):
            raise ConfigError(f"EPSG:{epsg} is not a WGS84 UTM zone (32601-32660 north, 32701-32760 south)")
        self.epsg = int(epsg)
        self._forward, self._inverse = _transformers(self.epsg)

    @classmethod
    def for_latlon(cls, lat: float, lon: float) -> "UtmProjector":
        """The projector of the UTM zone holding (lat, lon) degrees."""
        return cls(utm_epsg_for(lat, lon))

    @property
    def zone(self) -> int:
        """UTM zone number, 1..60."""
        return self.epsg % 100

    @property
    def north(self) -> bool:
        """True for a northern-hemisphere zone (326xx)."""
        return self.epsg < 32700

    def to_utm(self, lat: float | np.ndarray, lon: float | np.ndarray) -> tuple[float | np.ndarray, float | np.ndarray]:
        """(easting, northing) metres from WGS84 latitude, longitude degrees."""
        lat_a, lon_a = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
        e, n = self._forward.transform(lon_a, lat_a)
        e, n = np.asarray(e), np.asarray(n)
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(n))):
            raise DataError(f"EPSG:{self.epsg}: some lat/lon could not be projected (non-finite result)")
        return _out(e), _out(n)

    def to_latlon(self, e: float | np.ndarray, n: float | np.ndarray) -> tuple[float | np.ndarray, float | np.ndarray]:
        """(latitude, longitude) WGS84 degrees from easting, northing metres in this zone."""
        lon, lat = self._inverse.transform(np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64))
        lat, lon = np.asarray(lat), np.asarray(lon)
        if not (np.all(np.isfinite(lat)) and np.all(np.isfinite(lon))):
            raise DataError(f"EPSG:{self.epsg}: some easting/northing could not be unprojected (non-finite result)")
        return _out(lat), _out(lon)

    def grid_convergence(self, lat: float | np.ndarray, lon: float | np.ndarray) -> float | np.ndarray:
        """Meridian convergence gamma, radians, at WGS84 (lat, lon) degrees: the UTM grid heading is the true
        ENU heading plus gamma (theta_grid = theta_true + gamma). Negative west of the zone's central meridian
        in the northern hemisphere (about -0.46 deg at KITTI's Karlsruhe)."""
        factors = _proj(self.epsg).get_factors(np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64))
        return _out(np.radians(np.asarray(factors.meridian_convergence, dtype=np.float64)))

    def __repr__(self) -> str:
        return f"UtmProjector(epsg={self.epsg})"


def grid_convergence(lat: float | np.ndarray, lon: float | np.ndarray, epsg: int | None = None) -> float | np.ndarray:
    """Meridian convergence, radians, of UTM zone `epsg` (default: the zone of the first point) at (lat, lon)
    degrees; add it to a true ENU heading (OXTS yaw, a compass) to get the heading on the UTM grid."""
    if epsg is None:
        epsg = utm_epsg_for(float(np.ravel(lat)[0]), float(np.ravel(lon)[0]))
    return UtmProjector(epsg).grid_convergence(lat, lon)


# ------------------------------------------------------------------------------------------------ time

def gps_leap_seconds_at(unix_time_s: float) -> int:
    """GPS - UTC offset in seconds in force at a UTC (unix) time; 0 before 1981-07-01, 18 since 2017-01-01."""
    return sum(1 for t in _LEAP_UNIX_S if unix_time_s >= t)


def gps_week_ms(unix_time_s: float, leap_seconds: int = 18) -> tuple[int, int]:
    """GPS week number (not rolled over) and milliseconds into the week for a UTC unix time, seconds.

    `leap_seconds` is GPS - UTC (18 since 2017; `gps_leap_seconds_at` gives it for older data such as KITTI's
    15 s in 2011). The result rounds to the nearest millisecond.
    """
    if not math.isfinite(unix_time_s):
        raise DataError(f"unix time {unix_time_s}: not finite")
    total_ms = int(round((float(unix_time_s) - GPS_EPOCH_UNIX_S + leap_seconds) * 1000.0))
    if total_ms < 0:
        raise DataError(f"unix time {unix_time_s}: before the GPS epoch 1980-01-06")
    week, ms = divmod(total_ms, SECONDS_PER_WEEK * 1000)
    return int(week), int(ms)


def unix_from_gps_week_ms(week: int, ms: int, leap_seconds: int = 18) -> float:
    """UTC unix time, seconds, of a GPS week and millisecond of week (the inverse of `gps_week_ms`)."""
    return GPS_EPOCH_UNIX_S + week * SECONDS_PER_WEEK + ms / 1000.0 - leap_seconds
