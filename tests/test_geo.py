"""Tests of taco_mav.geo: UTM zones and projection, heading conventions, GPS time."""

from __future__ import annotations

import calendar
import math

import numpy as np
import pytest

from taco_mav.errors import ConfigError, DataError
from taco_mav.geo import (
    GPS_EPOCH_UNIX_S,
    UtmProjector,
    enu_from_ned_yaw,
    gps_leap_seconds_at,
    gps_week_ms,
    grid_convergence,
    ned_from_enu_yaw,
    unix_from_gps_week_ms,
    utm_epsg_for,
    wrap_angle,
)

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563


def krueger_utm(lat_deg: float, lon_deg: float, zone: int) -> tuple[float, float]:
    """Independent reference: transverse Mercator by Krueger's n-series to n^4 (nanometre-level in a zone),
    written from the textbook formulas so the test does not compare PROJ with itself."""
    n = WGS84_F / (2.0 - WGS84_F)
    big_a = WGS84_A / (1.0 + n) * (1.0 + n**2 / 4.0 + n**4 / 64.0)
    alpha = (
        n / 2.0 - 2.0 * n**2 / 3.0 + 5.0 * n**3 / 16.0 + 41.0 * n**4 / 180.0,
        13.0 * n**2 / 48.0 - 3.0 * n**3 / 5.0 + 557.0 * n**4 / 1440.0,
        61.0 * n**3 / 240.0 - 103.0 * n**4 / 140.0,
        49561.0 * n**4 / 161280.0,
    )
    phi = math.radians(lat_deg)
    lam = math.radians(lon_deg - (6.0 * zone - 183.0))
    c = 2.0 * math.sqrt(n) / (1.0 + n)
    t = math.sinh(math.atanh(math.sin(phi)) - c * math.atanh(c * math.sin(phi)))
    xi = math.atan2(t, math.cos(lam))
    eta = math.atanh(math.sin(lam) / math.sqrt(1.0 + t * t))
    e = eta + sum(a * math.cos(2 * j * xi) * math.sinh(2 * j * eta) for j, a in enumerate(alpha, 1))
    nn = xi + sum(a * math.sin(2 * j * xi) * math.cosh(2 * j * eta) for j, a in enumerate(alpha, 1))
    k0 = 0.9996
    return 500000.0 + k0 * big_a * e, (0.0 if lat_deg >= 0 else 10_000_000.0) + k0 * big_a * nn


@pytest.mark.parametrize(
    ("lat", "lon", "epsg"),
    [
        (49.0135, 8.4044, 32632),  # Karlsruhe palace
        (49.04951961077, 8.3965961639946, 32632),  # KITTI 2011_09_30_drive_0018 frame 0
        (-35.363261, 149.165230, 32755),  # ArduPilot SITL home, Canberra
        (-33.87, 151.21, 32756),  # Sydney
        (60.39, 5.32, 32632),  # Bergen: zone 32V is widened west
        (78.22, 15.65, 32633),  # Longyearbyen: Svalbard zone 33X
        (0.0, -180.0, 32601),
        (0.0, 180.0, 32660),
        (-0.001, 0.001, 32731),
    ],
)
def test_utm_epsg_for(lat: float, lon: float, epsg: int) -> None:
    assert utm_epsg_for(lat, lon) == epsg


@pytest.mark.parametrize(("lat", "lon"), [(85.0, 0.0), (-81.0, 0.0), (0.0, 181.0), (math.nan, 8.0)])
def test_utm_epsg_for_refuses_outside_utm(lat: float, lon: float) -> None:
    with pytest.raises(DataError, match="outside the UTM domain"):
        utm_epsg_for(lat, lon)


def test_karlsruhe_to_utm32n_matches_independent_series_within_1mm() -> None:
    proj = UtmProjector(32632)
    for lat, lon in [(49.0135, 8.4044), (49.04951961077, 8.3965961639946), (48.98, 8.50)]:
        e, n = proj.to_utm(lat, lon)
        e_ref, n_ref = krueger_utm(lat, lon, 32)
        assert abs(e - e_ref) < 1e-3 and abs(n - n_ref) < 1e-3
    # Hand-recorded reference for KITTI drive 0018 frame 0 (regression guard on PROJ's behaviour).
    e, n = proj.to_utm(49.04951961077, 8.3965961639946)
    assert e == pytest.approx(455909.4039, abs=1e-3)
    assert n == pytest.approx(5433136.0187, abs=1e-3)


def test_southern_zone_matches_series_with_false_northing() -> None:
    e, n = UtmProjector(32755).to_utm(-35.363261, 149.165230)
    e_ref, n_ref = krueger_utm(-35.363261, 149.165230, 55)
    assert abs(e - e_ref) < 1e-3 and abs(n - n_ref) < 1e-3
    assert 0 < n < 10_000_000


def test_round_trip_vectorised_is_sub_millimetre() -> None:
    rng = np.random.default_rng(0)
    lat = 49.0 + rng.uniform(-0.2, 0.2, 500)
    lon = 8.4 + rng.uniform(-0.2, 0.2, 500)
    proj = UtmProjector.for_latlon(49.0, 8.4)
    e, n = proj.to_utm(lat, lon)
    assert isinstance(e, np.ndarray) and e.shape == (500,)
    lat2, lon2 = proj.to_latlon(e, n)
    # 1e-9 degrees is ~0.1 mm.
    assert np.max(np.abs(lat2 - lat)) < 1e-9 and np.max(np.abs(lon2 - lon)) < 1e-9
    e2, n2 = proj.to_utm(lat2, lon2)
    assert np.max(np.hypot(e2 - e, n2 - n)) < 1e-4


def test_projector_scalars_and_properties() -> None:
    proj = UtmProjector(32755)
    e, n = proj.to_utm(-35.0, 149.0)
    assert isinstance(e, float) and isinstance(n, float)
    assert proj.zone == 55 and not proj.north
    assert UtmProjector(32632).north and UtmProjector(32632).zone == 32


@pytest.mark.parametrize("epsg", [4326, 32600, 32661, 32700, 3857])
def test_projector_refuses_non_utm_epsg(epsg: int) -> None:
    with pytest.raises(ConfigError, match=f"EPSG:{epsg}"):
        UtmProjector(epsg)


def test_grid_convergence_matches_spherical_formula() -> None:
    # gamma ~ atan(tan(lon - lon0) sin(lat)) to ~1e-5 rad within a zone; the grid heading is true heading + gamma.
    for lat, lon, epsg, lon0 in [(49.0495, 8.3966, 32632, 9.0), (49.0, 11.5, 32632, 9.0), (-35.36, 149.17, 32755, 147.0)]:
        expected = math.atan(math.tan(math.radians(lon - lon0)) * math.sin(math.radians(lat)))
        assert grid_convergence(lat, lon, epsg) == pytest.approx(expected, abs=2e-5)
    assert math.degrees(grid_convergence(49.04951961077, 8.3965961639946)) == pytest.approx(-0.4557, abs=1e-3)
    gammas = UtmProjector(32632).grid_convergence(np.array([49.0, 49.0]), np.array([8.0, 10.0]))
    assert gammas.shape == (2,) and gammas[0] < 0 < gammas[1] and gammas[0] == pytest.approx(-gammas[1], rel=1e-3)


def test_wrap_angle_range_and_shape() -> None:
    assert wrap_angle(math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-7.0) == pytest.approx(-7.0 + 2 * math.pi)
    a = np.linspace(-20, 20, 1001)
    w = wrap_angle(a)
    assert w.shape == a.shape and np.all(w >= -math.pi) and np.all(w < math.pi)
    assert np.allclose(np.sin(w), np.sin(a)) and np.allclose(np.cos(w), np.cos(a))
    assert isinstance(wrap_angle(1.0), float)


def test_heading_conventions() -> None:
    # NED yaw 0 = north -> ENU pi/2; NED pi/2 = east -> ENU 0; NED -pi/2 = west -> ENU pi (wrapped to -pi).
    assert enu_from_ned_yaw(0.0) == pytest.approx(math.pi / 2)
    assert enu_from_ned_yaw(math.pi / 2) == pytest.approx(0.0)
    assert enu_from_ned_yaw(math.pi) == pytest.approx(-math.pi / 2)
    assert abs(enu_from_ned_yaw(-math.pi / 2)) == pytest.approx(math.pi)
    assert ned_from_enu_yaw(0.0) == pytest.approx(math.pi / 2)
    theta = np.linspace(-math.pi, math.pi - 1e-9, 361)
    assert np.allclose(wrap_angle(enu_from_ned_yaw(ned_from_enu_yaw(theta)) - theta), 0.0, atol=1e-12)


def test_gps_week_known_dates() -> None:
    assert GPS_EPOCH_UNIX_S == 315964800
    assert gps_week_ms(GPS_EPOCH_UNIX_S, leap_seconds=0) == (0, 0)
    # Second week-number rollover: 2019-04-07 00:00:00 GPS time = week 2048, i.e. 23:59:42 UTC the day before.
    assert gps_week_ms(calendar.timegm((2019, 4, 7, 0, 0, 0)) - 18) == (2048, 0)
    # First rollover: 1999-08-22 00:00:00 GPS = week 1024 with GPS - UTC = 13 s.
    unix_1999 = calendar.timegm((1999, 8, 22, 0, 0, 0)) - 13
    assert gps_leap_seconds_at(unix_1999) == 13
    assert gps_week_ms(unix_1999, leap_seconds=13) == (1024, 0)
    # Monday 2024-01-01 00:00:00 UTC: one day and 18 s into week 2295.
    assert gps_week_ms(calendar.timegm((2024, 1, 1, 0, 0, 0))) == (2295, 86_418_000)
    assert gps_week_ms(calendar.timegm((2024, 1, 1, 0, 0, 0)) + 0.0126) == (2295, 86_418_013)


def test_leap_seconds_table() -> None:
    assert gps_leap_seconds_at(GPS_EPOCH_UNIX_S) == 0
    assert gps_leap_seconds_at(calendar.timegm((2011, 9, 30, 12, 0, 0))) == 15  # KITTI's recordings
    assert gps_leap_seconds_at(calendar.timegm((2016, 12, 31, 23, 59, 59))) == 17
    assert gps_leap_seconds_at(calendar.timegm((2017, 1, 1, 0, 0, 0))) == 18


def test_gps_round_trip_and_errors() -> None:
    t = 1_317_383_679.239
    week, ms = gps_week_ms(t, 15)
    assert unix_from_gps_week_ms(week, ms, 15) == pytest.approx(t, abs=5e-4)
    with pytest.raises(DataError, match="before the GPS epoch"):
        gps_week_ms(0.0)
    with pytest.raises(DataError, match="not finite"):
        gps_week_ms(math.nan)
