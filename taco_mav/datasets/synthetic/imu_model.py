"""IMU and attitude noise models for the synthetic drive, with data-sheet presets.

Continuous-time parameters (the usual Allan-variance names) and their discrete 100 Hz realisation:
- angle random walk N_g (rad/sqrt(s)): white gyro noise, per-sample std N_g / sqrt(dt);
- gyro bias instability sigma_bi (rad/s): first-order Gauss-Markov bias with correlation time tau (s);
- gyro rate random walk K_g (rad/s/sqrt(s)): bias random walk, per-step std K_g sqrt(dt);
- velocity random walk N_a (m/s/sqrt(s)): white accelerometer noise, per-sample std N_a / sqrt(dt);
- accelerometer bias instability / random walk: as for the gyro, in m/s^2 and m/s^2/sqrt(s);
- initial (turn-on residual) biases: constant, drawn once per axis, std in rad/s and m/s^2;
- vibration: white engine/road vibration on the accelerometer, m/s^2 per sample (not a sensor error, but what
  a body-mounted MEMS unit on a car reads);
- attitude output: heading (compass/AHRS) error as a Gauss-Markov process (std, tau) and roll/pitch error std.

Inputs and outputs are body FLU (x forward, y left, z up, as KITTI's OXTS ax..az / wx..wz), m/s^2 including
gravity and rad/s. Every draw comes from one `numpy.random.Generator` seeded by the caller.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import lfilter

from taco_mav.errors import ConfigError

__all__ = ["ImuNoiseModel", "PRESETS", "noise_preset", "apply_imu_noise", "gauss_markov"]

_DEG = math.pi / 180.0
_HOUR = 3600.0
_G = 9.80665


@dataclass(frozen=True)
class ImuNoiseModel:
    """A named IMU + attitude error model (units in the field comments; see the module docstring)."""

    name: str
    gyro_arw: float = 0.0  # rad/sqrt(s)
    gyro_bias_instability: float = 0.0  # rad/s (Gauss-Markov std)
    gyro_bias_tau_s: float = 100.0  # s
    gyro_bias_rw: float = 0.0  # rad/s/sqrt(s)
    gyro_initial_bias: float = 0.0  # rad/s, std of the constant turn-on residual
    accel_vrw: float = 0.0  # m/s/sqrt(s)
    accel_bias_instability: float = 0.0  # m/s^2 (Gauss-Markov std)
    accel_bias_tau_s: float = 100.0  # s
    accel_bias_rw: float = 0.0  # m/s^2/sqrt(s)
    accel_initial_bias: float = 0.0  # m/s^2, std of the constant turn-on residual
    vibration_accel: float = 0.0  # m/s^2 white, per sample
    heading_sigma: float = 0.0  # rad, Gauss-Markov std of the reported yaw
    heading_tau_s: float = 30.0  # s
    tilt_sigma: float = 0.0  # rad, std of the reported roll and pitch (Gauss-Markov, tau = heading_tau_s)

    def to_dict(self) -> dict[str, float | str]:
        """Plain mapping (written into world.json)."""
        return asdict(self)


PRESETS: dict[str, ImuNoiseModel] = {
    # Automotive-grade MEMS IMU (Bosch SMI/BMI-class, as in autopilots and car ECUs), after the autopilot's
    # start-up calibration: gyro ARW 0.3 deg/sqrt(h), bias instability 5 deg/h, rate random walk
    # 10 deg/h/sqrt(h), residual turn-on bias 0.02 deg/s; accelerometer noise density 120 ug/sqrt(Hz)
    # (VRW 0.07 m/s/sqrt(h)), bias instability 50 ug, residual bias 3 mg; 0.05 m/s^2 vibration;
    # compass/AHRS heading error 0.5 deg (tau 30 s), roll/pitch 0.2 deg.
    "automotive": ImuNoiseModel(
        name="automotive",
        gyro_arw=0.3 * _DEG / 60.0,
        gyro_bias_instability=5.0 * _DEG / _HOUR,
        gyro_bias_tau_s=100.0,
        gyro_bias_rw=10.0 * _DEG / _HOUR / 60.0,
        gyro_initial_bias=0.02 * _DEG,
        accel_vrw=120e-6 * _G,
        accel_bias_instability=50e-6 * _G,
        accel_bias_tau_s=100.0,
        accel_bias_rw=1e-5,
        accel_initial_bias=3e-3 * _G,
        vibration_accel=0.05,
        heading_sigma=0.5 * _DEG,
        heading_tau_s=30.0,
        tilt_sigma=0.2 * _DEG,
    ),
    # OXTS RT3003 (KITTI's GPS/IMU), data sheet: gyro ARW 0.2 deg/sqrt(h), bias stability 2 deg/h;
    # accelerometer bias stability 2 ug, noise density 20 ug/sqrt(Hz); heading 0.1 deg, roll/pitch 0.03 deg
    # (1 sigma, GNSS-aided as in KITTI).
    "rt3003": ImuNoiseModel(
        name="rt3003",
        gyro_arw=0.2 * _DEG / 60.0,
        gyro_bias_instability=2.0 * _DEG / _HOUR,
        gyro_bias_tau_s=300.0,
        gyro_bias_rw=1.0 * _DEG / _HOUR / 60.0,
        gyro_initial_bias=0.002 * _DEG,
        accel_vrw=20e-6 * _G,
        accel_bias_instability=2e-6 * _G,
        accel_bias_tau_s=300.0,
        accel_bias_rw=1e-6,
        accel_initial_bias=0.1e-3 * _G,
        vibration_accel=0.02,
        heading_sigma=0.1 * _DEG,
        heading_tau_s=60.0,
        tilt_sigma=0.03 * _DEG,
    ),
    # Noise-free: the IMU and attitude fields carry the exact kinematics.
    "none": ImuNoiseModel(name="none"),
}


def noise_preset(name: str) -> ImuNoiseModel:
    """The preset called `name` (automotive | rt3003 | none); ConfigError otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(f"--imu: unknown IMU preset {name!r} (known: {', '.join(PRESETS)})") from None


def gauss_markov(rng: np.random.Generator, n: int, dt: float, sigma: float, tau_s: float, dims: int = 3) -> np.ndarray:
    """A stationary first-order Gauss-Markov process, shape (n, dims), std `sigma`, correlation time `tau_s`."""
    if sigma <= 0.0 or n == 0:
        return np.zeros((n, dims))
    phi = math.exp(-dt / tau_s)
    q = sigma * math.sqrt(1.0 - phi * phi)
    w = rng.standard_normal((n, dims)) * q
    w[0] = rng.standard_normal(dims) * sigma
    # x_k = phi x_{k-1} + w_k, solved as a linear recursive filter (vectorised).
    return lfilter([1.0], [1.0, -phi], w, axis=0)


def _random_walk(rng: np.random.Generator, n: int, dt: float, k: float) -> np.ndarray:
    if k <= 0.0 or n == 0:
        return np.zeros((n, 3))
    steps = rng.standard_normal((n, 3)) * (k * math.sqrt(dt))
    steps[0] = 0.0
    return np.cumsum(steps, axis=0)


def apply_imu_noise(
    model: ImuNoiseModel,
    accel_flu: np.ndarray,
    gyro_flu: np.ndarray,
    rpy: np.ndarray,
    dt: float,
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy copies of true body FLU specific force (N, 3) m/s^2, gyro (N, 3) rad/s and attitude (N, 3)
    (roll, pitch, yaw radians in KITTI's convention; yaw is wrapped to [-pi, pi)). `dt`: sample period, s."""
    n = len(accel_flu)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1A0]))
    g_bias = (rng.standard_normal(3) * model.gyro_initial_bias
              + gauss_markov(rng, n, dt, model.gyro_bias_instability, model.gyro_bias_tau_s)
              + _random_walk(rng, n, dt, model.gyro_bias_rw))
    a_bias = (rng.standard_normal(3) * model.accel_initial_bias
              + gauss_markov(rng, n, dt, model.accel_bias_instability, model.accel_bias_tau_s)
              + _random_walk(rng, n, dt, model.accel_bias_rw))
    gyro = gyro_flu + g_bias + rng.standard_normal((n, 3)) * (model.gyro_arw / math.sqrt(dt))
    white_a = math.hypot(model.accel_vrw / math.sqrt(dt), model.vibration_accel)
    accel = accel_flu + a_bias + rng.standard_normal((n, 3)) * white_a
    att = np.array(rpy, dtype=np.float64, copy=True)
    att[:, :2] += gauss_markov(rng, n, dt, model.tilt_sigma, model.heading_tau_s, dims=2)
    att[:, 2] += gauss_markov(rng, n, dt, model.heading_sigma, model.heading_tau_s, dims=1)[:, 0]
    att[:, 2] = np.mod(att[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    return accel, gyro, att
