"""Builders for tests: simulated IMU streams and trajectories, and an oracle 'matcher' with known noise.

Frames: truth is ENU metres / ENU heading; IMU samples are what an autopilot reports (FRD specific force incl.
gravity, FRD gyro, NED attitude).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from taco_mav.core.search import body_to_world
from taco_mav.core.types import FixQuery, ImuSample, MatchResult

G = 9.80665


@dataclass
class SimDrive:
    """t: (N,) s; xy: (N, 2) ENU m; theta: (N,) rad; speed: (N,) m/s; samples: IMU samples at the same times."""

    t: np.ndarray
    xy: np.ndarray
    theta: np.ndarray
    speed: np.ndarray
    samples: list[ImuSample]

    def pose_at(self, t: float) -> tuple[float, float, float]:
        i = int(np.clip(np.searchsorted(self.t, t - 1e-9), 0, len(self.t) - 1))
        return float(self.xy[i, 0]), float(self.xy[i, 1]), float(self.theta[i])

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.xy, axis=0), axis=1).sum())


def simulate(speed_fn, yaw_rate_fn, duration: float, rate_hz: float = 100.0, theta0: float = 0.0,
             accel_noise: float = 0.0, gyro_noise: float = 0.0, compass_noise: float = 0.0, seed: int = 0,
             pitch: float = 0.0, roll: float = 0.0) -> SimDrive:
    """Integrate a planar drive from speed(t) m/s and yaw_rate(t) rad/s (CCW) and synthesise its IMU.
    With nonzero constant pitch/roll the vehicle is tilted (as on a banked road) and gravity is rotated."""
    rng = np.random.default_rng(seed)
    n = int(round(duration * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    v = np.array([speed_fn(ti) for ti in t], dtype=float)
    w = np.array([yaw_rate_fn(ti) for ti in t], dtype=float)
    dt = 1.0 / rate_hz
    theta = theta0 + np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)])
    mid = theta[:-1] + 0.5 * np.diff(theta)
    step = 0.5 * (v[1:] + v[:-1]) * dt
    xy = np.zeros((n, 2))
    xy[1:, 0] = np.cumsum(step * np.cos(mid))
    xy[1:, 1] = np.cumsum(step * np.sin(mid))
    a_fwd = np.gradient(v, dt)
    samples = []
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    for i in range(n):
        # level-frame specific force (forward, right, down) = (a_fwd, -v w, -g); rotate into the tilted body.
        f_level = np.array([a_fwd[i], -v[i] * w[i], -G])
        Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        f_body = (Ry @ Rx).T @ f_level + rng.normal(0.0, accel_noise, 3)
        gyro = np.array([0.0, 0.0, -w[i]]) + rng.normal(0.0, gyro_noise, 3)
        yaw = math.pi / 2 - theta[i] + rng.normal(0.0, compass_noise)
        samples.append(ImuSample(float(t[i]), tuple(map(float, f_body)), tuple(map(float, gyro)), roll, pitch,
                                 math.atan2(math.sin(yaw), math.cos(yaw))))
    return SimDrive(t, xy, np.arctan2(np.sin(theta), np.cos(theta)), v, samples)


class OracleMatcher:
    """Answers a FixQuery from the true pose at capture time with Gaussian body-frame noise (sigma_fwd,
    sigma_lat metres) and weight w; crops farther than capture_radius from truth get w = 0.05 and a random t."""

    def __init__(self, drive: SimDrive, sigma_fwd: float = 0.5, sigma_lat: float = 1.0, w: float = 1.0,
                 capture_radius: float = 20.0, seed: int = 0) -> None:
        self.drive, self.sf, self.sl, self.w, self.r = drive, sigma_fwd, sigma_lat, w, capture_radius
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def answer(self, q: FixQuery, psi_res: float = 0.0, bias_world: np.ndarray | None = None) -> list[MatchResult]:
        x, y, th = self.drive.pose_at(q.capture_t)
        self.rng = np.random.default_rng([self.seed, int(round(q.capture_t * 1000))])  # same answer at any latency
        true = np.array([x, y]) + (bias_world if bias_world is not None else 0.0)
        noise_world = body_to_world(th, np.array([self.rng.normal(0, self.sf), self.rng.normal(0, self.sl)]))
        R = np.array([[math.cos(psi_res), -math.sin(psi_res)], [math.sin(psi_res), math.cos(psi_res)]])
        out = []
        for c in q.crop_centres:
            rel_world = true + noise_world - c
            c_, s_ = math.cos(q.heading), math.sin(q.heading)
            t_body = np.array([c_ * rel_world[0] + s_ * rel_world[1], -s_ * rel_world[0] + c_ * rel_world[1]])
            if np.linalg.norm(true - c) > self.r:
                out.append(MatchResult(R, self.rng.uniform(-20, 20, 2), 0.05))
            else:
                out.append(MatchResult(R, t_body, self.w * (1.0 - 0.01 * np.linalg.norm(true - c))))
        return out


def wheel_distances(drive: SimDrive, pos_y: tuple[float, float] = (0.15, -0.15), radius_ratio: float = 1.0
                    ) -> np.ndarray:
    """Cumulative distances (N, 2), metres, that two wheel encoders at lateral positions pos_y (body FRD y, m)
    report along `drive` (each wheel moves at v + w_enu y), with the wheel radius configured radius_ratio times
    the true one (1.05: 5 % too large, every distance 5 % long)."""
    dt = np.diff(drive.t)
    w_enu = np.gradient(np.unwrap(drive.theta), drive.t)
    out = np.zeros((len(drive.t), 2))
    for i, y in enumerate(pos_y):
        v = drive.speed + w_enu * y
        out[1:, i] = np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)
    return radius_ratio * out
