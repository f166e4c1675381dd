"""Shadows for the GNSS guard (guard.py): IMU-only dead reckoning that neither GNSS nor camera fixes touch, and
the filter's state at an earlier frame carried forward by it. Pure maths.

`DeadReckoner` integrates the forward acceleration to a raw speed (bias and all) along the compass heading, and
keeps the integrals that restart it from any anchor's speed, accelerometer bias and compass bias in O(1):
for v(s) = v_a + v_raw(s) - v_raw(t_a) - b (s - t_a), the displacement since t_a is
dp_raw + (v_a - v_raw(t_a)) dA - b dC with A = integral of h ds and C = integral of (s - t_a) h ds (h the unit
heading vector, rotated by -beta for the compass bias). `shadow` and `shadow_velocity` give an `Anchor`'s
position and velocity at a later snapshot with their modelled error growth.

Frames and units: ENU metres on the UTM grid; headings ENU radians; speeds m/s; times autopilot seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taco_mav.core.gnss.params import GnssParams
from taco_mav.core.preintegration import wrap_angle
from taco_mav.core.ukf import fix_covariance


@dataclass(frozen=True, slots=True)
class DrSnap:
    """`DeadReckoner` accumulators at time t. tr: t - t0, s; p: raw dead-reckoned position, ENU m; v: raw
    integrated speed, m/s; a: integral of the unit heading vector, s; c: integral of (s - t0) times it, s^2;
    theta: compass heading at t, ENU rad."""

    t: float
    tr: float
    p: tuple[float, float]
    v: float
    a: tuple[float, float]
    c: tuple[float, float]
    theta: float = 0.0


class DeadReckoner:
    """IMU-only dead reckoning that GNSS and camera fixes never touch: forward acceleration integrated to a raw
    speed (bias and all), compass heading (ENU grid rad), and the integrals that let `shadow` restart it from
    any anchor's speed and accelerometer bias in O(1): for v(s) = v_a + v_raw(s) - v_raw(t_a) - b (s - t_a),
    the displacement since t_a is dp_raw + (v_a - v_raw(t_a)) dA - b dC with A = integral of h ds and
    C = integral of (s - t_a) h ds (h the unit heading vector)."""

    def __init__(self, t0: float, theta: float) -> None:
        self.t0, self.t, self.theta = t0, t0, theta
        self.px = self.py = self.v = 0.0
        self.ax = self.ay = self.cx = self.cy = 0.0

    def add(self, t: float, dt: float, accel_fwd: float, theta: float) -> None:
        """One IMU step of dt seconds ending at t: forward acceleration m/s^2, compass heading ENU rad (the
        Preintegrator's trapezoid on speed and mid-step heading)."""
        if dt <= 0.0:
            return
        mid = self.theta + 0.5 * wrap_angle(theta - self.theta)
        c, s = math.cos(mid), math.sin(mid)
        v0 = self.v
        self.v = v0 + accel_fwd * dt
        step = 0.5 * (v0 + self.v) * dt
        tm = (t - 0.5 * dt) - self.t0
        self.px += step * c
        self.py += step * s
        self.ax += dt * c
        self.ay += dt * s
        self.cx += tm * dt * c
        self.cy += tm * dt * s
        self.t, self.theta = t, theta

    def snap(self) -> DrSnap:
        return DrSnap(self.t, self.t - self.t0, (self.px, self.py), self.v, (self.ax, self.ay), (self.cx, self.cy),
                      self.theta)


@dataclass(frozen=True)
class Anchor:
    """The filter's state at time t, where a shadow starts. xy: ENU m (2,); cov: 2x2 m^2, its error about
    the receiver's bias track (what the receiver's later readings see); speed: true-speed
    estimate, m/s; accel_bias: m/s^2 (the raw speed drifts by +b per second); compass_bias: rad (the compass
    reads theta + beta); snap: the dead reckoner at t."""

    t: float
    xy: np.ndarray
    cov: np.ndarray
    speed: float
    accel_bias: float
    compass_bias: float
    snap: DrSnap
    sigma_speed: float = 0.0  # 1-sigma of speed, m/s, accel_bias, m/s^2, and heading, rad, as the estimator has them
    sigma_accel_bias: float = 0.0
    sigma_heading: float = 0.0
    bias_estimated: bool = True  # False: the estimator has no accelerometer-bias state (paper mode)


def dr_displacement(anchor: Anchor, a: DrSnap, b: DrSnap) -> np.ndarray:
    """Dead-reckoned displacement from snapshot a to snapshot b (ENU m, (2,)) with the anchor's speed,
    accelerometer bias and compass bias."""
    s0 = anchor.snap
    dax, day = b.a[0] - a.a[0], b.a[1] - a.a[1]
    # integral over [a.t, b.t] of (s - s0.t) h ds
    dcx = (b.c[0] - a.c[0]) - s0.tr * dax
    dcy = (b.c[1] - a.c[1]) - s0.tr * day
    dv = anchor.speed - s0.v
    bias = anchor.accel_bias
    dx = (b.p[0] - a.p[0]) + dv * dax - bias * dcx
    dy = (b.p[1] - a.p[1]) + dv * day - bias * dcy
    cb, sb = math.cos(anchor.compass_bias), math.sin(anchor.compass_bias)  # true heading = compass - beta
    return np.array([cb * dx + sb * dy, -sb * dx + cb * dy])


def shadow(anchor: Anchor, snap: DrSnap, p: GnssParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The anchor carried to snap.t by dead reckoning alone: (position ENU m (2,), the IMU's drift since the
    anchor from the dr_* parameters (2x2 m^2), the growth of the anchor's own speed, accelerometer-bias and
    heading uncertainty (2x2 m^2)). Along the track a speed error grows as sigma_v tau and an acceleration
    error as sigma_a tau^2 / 2, across it a heading error times the distance; the drift adds a random walk.
    The anchor's position covariance is not included."""
    d = dr_displacement(anchor, anchor.snap, snap)
    age = max(snap.t - anchor.t, 0.0)
    dist = float(np.hypot(*d))
    heading = math.atan2(d[1], d[0]) if dist > 1e-3 else 0.0

    def grow(sv: float, sa: float, sh: float, rw: float) -> np.ndarray:
        along = (sv * age) ** 2 + (0.5 * sa * age * age) ** 2 + rw
        cross = (sh * dist) ** 2 + rw
        return fix_covariance(heading, math.sqrt(along), math.sqrt(cross))

    sa = p.dr_accel_sigma_mps2 + (0.0 if anchor.bias_estimated else p.dr_accel_bias_sigma_mps2)
    drift = grow(p.dr_speed_sigma_mps, sa, p.dr_heading_sigma_rad, p.dr_pos_rw_mps**2 * age)
    own = grow(anchor.sigma_speed, anchor.sigma_accel_bias, anchor.sigma_heading, 0.0)
    return anchor.xy + d, drift, own


def shadow_velocity(anchor: Anchor, snap: DrSnap, p: GnssParams) -> tuple[np.ndarray, np.ndarray]:
    """The shadow's ground velocity at snap.t (ENU m/s (2,)): the anchor's speed plus the raw speed gained
    since less the bias, along the compass heading less the anchor's compass bias; and its covariance
    (2x2 (m/s)^2): along the track the anchor's speed and bias uncertainty and the dr_* drift, across it the
    speed times the heading uncertainty."""
    age = max(snap.t - anchor.t, 0.0)
    speed = anchor.speed + snap.v - anchor.snap.v - anchor.accel_bias * age
    heading = snap.theta - anchor.compass_bias
    sa = p.dr_accel_sigma_mps2 + anchor.sigma_accel_bias + (0.0 if anchor.bias_estimated else
                                                            p.dr_accel_bias_sigma_mps2)
    along = anchor.sigma_speed**2 + p.dr_speed_sigma_mps**2 + (sa * age) ** 2
    cross = (speed * (anchor.sigma_heading + p.dr_heading_sigma_rad)) ** 2
    h = np.array([math.cos(heading), math.sin(heading)])
    return speed * h, fix_covariance(heading, math.sqrt(along), math.sqrt(cross))


# ---------------------------------------------------------------------------------------------- the guard


def interpolate(snaps: list[DrSnap], t: float) -> DrSnap | None:
    """The dead reckoner at t, linear between the two snapshots around it (None outside their span)."""
    if not snaps or t < snaps[0].t - 1e-9 or t > snaps[-1].t + 1e-9:
        return None
    for a, b in zip(snaps, snaps[1:]):
        if a.t <= t <= b.t:
            if b.t - a.t < 1e-9:
                return a
            f = (t - a.t) / (b.t - a.t)

            def mix(u: tuple[float, float], w: tuple[float, float]) -> tuple[float, float]:
                return (u[0] + f * (w[0] - u[0]), u[1] + f * (w[1] - u[1]))

            return DrSnap(t, a.tr + f * (b.tr - a.tr), mix(a.p, b.p), a.v + f * (b.v - a.v), mix(a.a, b.a),
                          mix(a.c, b.c), b.theta)
    return snaps[-1]
