"""Local geometry of a closed-loop mission: metres east and north about the autopilot's home (equirectangular,
fine over a few hundred metres) and the square the rover drives."""

from __future__ import annotations

import math

EARTH_RADIUS_M = 6378137.0


def metres_between(lat0: float, lon0: float, lat1: float, lon1: float) -> tuple[float, float]:
    """(east, north) metres from point 0 to point 1 (equirectangular; fine over a few hundred metres)."""
    r = EARTH_RADIUS_M
    return (math.radians(lon1 - lon0) * r * math.cos(math.radians(lat0)), math.radians(lat1 - lat0) * r)


def offset(lat: float, lon: float, east: float, north: float) -> tuple[float, float]:
    """(lat, lon) degrees `east`, `north` metres from (lat, lon)."""
    r = EARTH_RADIUS_M
    return lat + math.degrees(north / r), lon + math.degrees(east / (r * math.cos(math.radians(lat))))


def square_corners(side: float) -> list[tuple[float, float]]:
    """The mission's square from home, (east, north) metres: N, E, S, W legs."""
    return [(0.0, side), (side, side), (side, 0.0), (0.0, 0.0)]
