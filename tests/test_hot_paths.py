"""The per-IMU-sample hot paths written for speed against their straightforward references: the
Preintegrator's step (helpers inlined) and the StationaryDetector's window (parallel deques). Random streams with
a seed; the rewrites keep every operation and its order, so the comparison is exact."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from taco_mav.core.preintegration import Preintegrator, enu_heading, level_forward_accel, wrap_angle
from taco_mav.core.plus.stationary import StationaryDetector
from taco_mav.core.types import ImuSample


class ReferencePreintegrator(Preintegrator):
    """Preintegrator.add as written before the hot-path rewrite (calls to the helper functions)."""

    def add(self, sample: ImuSample) -> float:
        dt = sample.t - self.t
        if dt <= 0.0:
            return 0.0
        self.t = sample.t
        dt = min(dt, self.max_dt_s)
        a = level_forward_accel(sample.accel_frd, sample.roll, sample.pitch)
        theta = wrap_angle(enu_heading(sample.yaw) + self.heading_offset)
        self.compass = theta  # the compass heading the filter fuses (Increment.theta_end); theta in compass mode
        v0 = self.speed
        v1 = v0 + a * dt
        if not self.allow_reverse and v1 < 0.0:
            v1 = 0.0
        step = 0.5 * (v0 + v1) * dt
        mid = self.theta + 0.5 * wrap_angle(theta - self.theta)
        cm, sm = math.cos(mid), math.sin(mid)
        ex, ey = step * cm, step * sm
        self.x += ex
        self.y += ey
        self._dx += ex
        self._dy += ey
        self._dist += abs(step)
        self._dt += dt
        self.speed = v1
        self.theta = theta
        self.accel_fwd = a
        return dt


class ReferenceStationary:
    """StationaryDetector as written before (one deque of tuples, generator sums)."""

    def __init__(self, window_s: float, gyro_max: float, accel_std_max: float,
                 accel_mean_max: float = math.inf) -> None:
        self.window_s, self.gyro_max = window_s, gyro_max
        self.accel_std_max, self.accel_mean_max = accel_std_max, accel_mean_max
        self._samples: deque = deque(maxlen=4096)

    def add(self, t, accel, gyro, accel_fwd=0.0) -> None:
        self._samples.append((t, tuple(accel), math.sqrt(sum(g * g for g in gyro)), accel_fwd))
        while self._samples and self._samples[0][0] < t - self.window_s:
            self._samples.popleft()

    def still(self, accel_bias: float = 0.0) -> bool:
        s = self._samples
        if len(s) < 3 or s[-1][0] - s[0][0] < 0.8 * self.window_s:
            return False
        if max(g for _, _, g, _ in s) > self.gyro_max:
            return False
        n = len(s)
        if abs(sum(a for _, _, _, a in s) / n - accel_bias) > self.accel_mean_max:
            return False
        var = 0.0
        for axis in range(3):
            mean = sum(f[axis] for _, f, _, _ in s) / n
            var += sum((f[axis] - mean) ** 2 for _, f, _, _ in s) / (n - 1)
        return math.sqrt(var) <= self.accel_std_max


def _stream(rng: np.random.Generator, n: int) -> list[ImuSample]:
    """Irregular 100 Hz samples (repeats, back-steps, gaps) with headings across the +-pi wrap and stops."""
    out, t = [], 5.0
    for i in range(n):
        t += float(rng.choice([0.01, 0.0, -0.003, 0.012, 0.7], p=[0.9, 0.03, 0.02, 0.04, 0.01]))
        moving = (i // 300) % 2 == 0
        acc = (float(rng.normal(0.2 if moving else 0.0, 0.5 if moving else 0.01)), float(rng.normal(0, 0.02)),
               float(-9.80665 + rng.normal(0, 0.02)))
        gyr = tuple(float(v) for v in rng.normal(0, 0.05 if moving else 0.002, 3))
        out.append(ImuSample(t, acc, gyr, float(rng.normal(0, 0.05)), float(rng.normal(0, 0.05)),
                             float(rng.uniform(-math.pi, math.pi) if i % 97 == 0 else math.pi - 0.01 * (i % 3))))
    return out


def test_preintegrator_step_matches_reference_bit_for_bit() -> None:
    rng = np.random.default_rng(11)
    for allow_reverse in (False, True):
        fast = Preintegrator(5.0, 1.0, 2.0, 3.0, 4.0, allow_reverse=allow_reverse, heading_offset=0.0123)
        ref = ReferencePreintegrator(5.0, 1.0, 2.0, 3.0, 4.0, allow_reverse=allow_reverse, heading_offset=0.0123)
        for k, s in enumerate(_stream(rng, 3000)):
            assert fast.add(s) == ref.add(s)
            state = lambda p: (p.t, p.x, p.y, p.theta, p.compass, p.speed, p.accel_fwd, p._dx, p._dy, p._dist,  # noqa: E731
                               p._dt)
            assert state(fast) == state(ref)
            if k % 10 == 0:
                assert fast.take_increment() == ref.take_increment()


def test_stationary_detector_matches_reference() -> None:
    rng = np.random.default_rng(12)
    fast = StationaryDetector(1.0, 0.02, 0.05, 0.15)
    ref = ReferenceStationary(1.0, 0.02, 0.05, 0.15)
    answers = []
    for s in _stream(rng, 4000):
        a = float(rng.normal(0, 0.05))
        fast.add(s.t, s.accel_frd, s.gyro_frd, a)
        ref.add(s.t, s.accel_frd, s.gyro_frd, a)
        bias = float(rng.normal(0, 0.02))
        answers.append(fast.still(bias))
        assert answers[-1] == ref.still(bias)
        assert fast.stationary == ref.still(0.0)
    assert any(answers) and not all(answers)  # both branches were exercised
