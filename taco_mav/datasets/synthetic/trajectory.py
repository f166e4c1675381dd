"""Vehicle kinematics along a driven line: a smooth path, a speed profile, and exact truth at the IMU rate.

Frame: local ENU metres (x east, y north); heading ENU radians (0 = east, CCW), unwrapped (continuous).
The driven line is smoothed with a Gaussian along arc length (a 90 degree corner becomes a turn of about 10 m
minimum radius). Speed is the largest profile under: a cruise speed per street (uniform in `cruise_mps`),
lateral acceleration <= `max_lat_accel`, acceleration <= `max_accel`, braking <= `max_decel`, and full stops
(with dwell) before some junctions. Speed in time is lightly low-passed so the jerk is bounded, and the
position is the arc-length integral of that speed, so speed, position, heading and yaw rate agree exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from taco_mav.datasets.synthetic.roads import resample_polyline

__all__ = ["Kinematics", "smooth_path", "speed_limits", "drive_kinematics"]


@dataclass(frozen=True)
class Kinematics:
    """Exact truth at a fixed rate. t: (N,) s from 0; xy: (N, 2) local ENU metres; heading: (N,) ENU radians,
    unwrapped; speed: (N,) m/s; accel_fwd: (N,) dv/dt m/s^2; yaw_rate: (N,) rad/s (CCW); accel_lat: (N,)
    centripetal m/s^2, positive to the left; s: (N,) arc length driven, metres."""

    t: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    accel_fwd: np.ndarray
    yaw_rate: np.ndarray
    accel_lat: np.ndarray
    s: np.ndarray


def smooth_path(xy: np.ndarray, offset_right: np.ndarray | None = None, sigma_m: float = 6.0,
                sharp_sigma_m: float = 14.0, step_m: float = 0.25) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gaussian-smoothed path, optionally shifted `offset_right` (N,) metres to the right of the smoothed
    line (a lane offset, itself smoothed). Gentle bends are smoothed with `sigma_m`, sharp turns (over 40
    degrees within 30 m) blend smoothly towards `sharp_sigma_m` so a 90 degree junction turn has a radius of
    about 13 m (about 10 m on the inner lane). Returns s (M,) arc length metres, xy (M, 2), heading (M,)
    unwrapped ENU radians and curvature (M,) 1/m (positive = turning left), at uniform `step_m` spacing."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s_in = np.r_[0.0, np.cumsum(seg)]
    dense = resample_polyline(xy, step_m)
    fine = gaussian_filter1d(dense, sigma_m / step_m, axis=0, mode="nearest")
    wide = gaussian_filter1d(dense, sharp_sigma_m / step_m, axis=0, mode="nearest")
    d = np.gradient(fine, axis=0)
    th = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    half = int(round(15.0 / step_m))
    idx = np.arange(len(th))
    turn = np.abs(th[np.minimum(idx + half, len(th) - 1)] - th[np.maximum(idx - half, 0)])
    w = np.clip((turn - np.radians(40.0)) / np.radians(40.0), 0.0, 1.0)
    w = gaussian_filter1d(maximum_filter1d(w, 2 * half + 1), 10.0 / step_m, mode="nearest")
    sm = fine + w[:, None] * (wide - fine)
    if offset_right is not None:
        s_d = np.linspace(0.0, s_in[-1], len(dense))
        off = gaussian_filter1d(np.interp(s_d, s_in, offset_right), sigma_m / step_m, mode="nearest")
        d = np.gradient(sm, axis=0)
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        sm = sm + np.c_[d[:, 1], -d[:, 0]] * off[:, None]
        sm = gaussian_filter1d(sm, 1.0 / step_m, axis=0, mode="nearest")
    sm = resample_polyline(sm, step_m)
    d = np.gradient(sm, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sm, axis=0), axis=1))]
    curvature = gaussian_filter1d(np.gradient(heading, s), 0.5 / step_m, mode="nearest")
    return s, sm, heading, curvature


def speed_limits(s: np.ndarray, curvature: np.ndarray, cruise: np.ndarray, stops: np.ndarray,
                 max_accel: float, max_decel: float, max_lat_accel: float) -> np.ndarray:
    """Speed profile v(s) (M,) m/s: min(cruise, sqrt(a_lat / |k|)), zero at `stops` (arc lengths, metres) and
    at both ends, then limited by forward acceleration and backward braking passes."""
    k = maximum_filter1d(np.abs(curvature), 9)  # the largest curvature within about +-1 m
    v = np.minimum(cruise, np.sqrt(max_lat_accel / np.maximum(k, 1e-6)))
    v[0] = v[-1] = 0.0
    if len(stops):
        v[np.clip(np.searchsorted(s, stops), 0, len(s) - 1)] = 0.0
    ds = np.diff(s)
    v2 = v * v
    for i in range(1, len(v2)):
        v2[i] = min(v2[i], v2[i - 1] + 2.0 * max_accel * ds[i - 1])
    for i in range(len(v2) - 2, -1, -1):
        v2[i] = min(v2[i], v2[i + 1] + 2.0 * max_decel * ds[i])
    return np.sqrt(v2)


def drive_kinematics(line_xy: np.ndarray, junction_idx: np.ndarray, rng: np.random.Generator,
                     offset_right: np.ndarray | None = None,
                     rate_hz: float = 100.0, cruise_mps: tuple[float, float] = (8.0, 12.0),
                     max_accel: float = 1.5, max_decel: float = 2.0, max_lat_accel: float = 2.0,
                     stop_probability: float = 0.35, rest_s: float = 3.0) -> Kinematics:
    """Truth at `rate_hz` for a drive along `line_xy` (N, 2) local ENU metres (kept `offset_right` (N,) metres
    to its right, e.g. in the right-hand lane), whose junctions are at indices `junction_idx`. The vehicle rests `rest_s` at the start and at the end, and stops (2-6 s) about 8 m
    before a share `stop_probability` of the intermediate junctions."""
    seg = np.linalg.norm(np.diff(line_xy, axis=0), axis=1)
    s_line = np.r_[0.0, np.cumsum(seg)]
    s, xy, heading, curv = smooth_path(line_xy, offset_right)
    s_j = s_line[np.asarray(junction_idx)] * (s[-1] / s_line[-1])
    cruise_edges = rng.uniform(*cruise_mps, len(s_j) + 1)
    cruise = cruise_edges[np.searchsorted(s_j, s)]
    inner = s_j[1:-1]
    stop_mask = rng.random(len(inner)) < stop_probability
    stops = np.clip(inner[stop_mask] - 8.0, 1.0, s[-1] - 1.0)
    dwell = rng.uniform(2.0, 6.0, len(stops))
    v = speed_limits(s, curv, cruise, stops, max_accel, max_decel, max_lat_accel)

    # Arc length -> time (trapezoid on 1/v), with dwell inserted at each stop and rests at both ends.
    vm = 0.5 * (v[1:] + v[:-1])
    t_s = np.r_[0.0, np.cumsum(np.diff(s) / np.maximum(vm, 1e-3))] + rest_s
    stop_i = np.clip(np.searchsorted(s, stops), 0, len(s) - 1)
    order = np.argsort(stop_i)
    for i, w in zip(stop_i[order][::-1], dwell[order][::-1]):
        t_s[i + 1:] += w
    # Knots: (t, s), with each stop duplicated at arrival and departure, the rests at the ends.
    t_knots = [np.array([0.0]), t_s]
    s_knots = [np.array([0.0]), s]
    for i, w in zip(stop_i, dwell):
        t_knots.append(np.array([t_s[i] + w]))
        s_knots.append(np.array([s[i]]))
    t_end = t_s[-1] + rest_s
    t_knots.append(np.array([t_end]))
    s_knots.append(np.array([s[-1]]))
    tk, sk = np.concatenate(t_knots), np.concatenate(s_knots)
    o = np.lexsort((sk, tk))
    tk, sk = tk[o], sk[o]

    dt = 1.0 / rate_hz
    n = int(np.floor(t_end * rate_hz)) + 1
    t = np.arange(n) * dt
    s_t = np.interp(t, tk, sk)
    speed = gaussian_filter1d(np.gradient(s_t, dt), 0.25 * rate_hz, mode="nearest")
    speed = np.maximum(speed, 0.0)
    speed[:2] = 0.0
    speed[-2:] = 0.0
    s_t = np.r_[0.0, np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt)]
    s_t = np.minimum(s_t, s[-1])
    x = np.interp(s_t, s, xy[:, 0])
    y = np.interp(s_t, s, xy[:, 1])
    hd = np.interp(s_t, s, heading)
    yaw_rate = np.gradient(hd, dt)
    accel = np.gradient(speed, dt)
    return Kinematics(t=t, xy=np.c_[x, y], heading=hd, speed=speed, accel_fwd=accel, yaw_rate=yaw_rate,
                      accel_lat=speed * yaw_rate, s=s_t)
