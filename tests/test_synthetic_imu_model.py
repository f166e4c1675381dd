"""IMU noise presets: exact pass-through without noise, white-noise levels and Gauss-Markov statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from taco_mav.config import ImuParams
from taco_mav.datasets.synthetic.imu_model import PRESETS, ImuNoiseModel, apply_imu_noise, gauss_markov, noise_preset
from taco_mav.errors import ConfigError

DT = 0.01


def _still(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.tile([0.0, 0.0, 9.80665], (n, 1)), np.zeros((n, 3)), np.zeros((n, 3))


def test_none_preset_is_exact():
    a, g, r = _still(1000)
    r[:, 2] = 1.0
    a2, g2, r2 = apply_imu_noise(noise_preset("none"), a, g, r, DT, seed=3)
    assert np.array_equal(a2, a) and np.array_equal(g2, g) and np.array_equal(r2, r)


def test_unknown_preset_names_the_choices():
    with pytest.raises(ConfigError, match="automotive"):
        noise_preset("tactical")


def test_white_noise_levels_match_arw_and_vrw():
    model = ImuNoiseModel(name="white", gyro_arw=PRESETS["automotive"].gyro_arw, accel_vrw=PRESETS["automotive"].accel_vrw)
    a, g, r = _still(200_000)
    a2, g2, _ = apply_imu_noise(model, a, g, r, DT, seed=1)
    assert np.std(g2, axis=0) == pytest.approx(np.full(3, model.gyro_arw / math.sqrt(DT)), rel=0.02)
    assert np.std(a2 - a, axis=0) == pytest.approx(np.full(3, model.accel_vrw / math.sqrt(DT)), rel=0.02)


def test_automotive_gyro_arw_matches_the_default_profile():
    assert PRESETS["automotive"].gyro_arw == pytest.approx(ImuParams().gyro_arw, rel=1e-12)
    assert PRESETS["automotive"].heading_sigma == pytest.approx(math.radians(0.5))


def test_gauss_markov_is_stationary_with_the_given_std_and_correlation():
    x = gauss_markov(np.random.default_rng(0), 400_000, DT, sigma=0.2, tau_s=1.0, dims=1)[:, 0]
    assert np.std(x) == pytest.approx(0.2, rel=0.05)
    lag = int(1.0 / DT)  # autocorrelation at one tau is exp(-1)
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert rho == pytest.approx(math.exp(-1.0), abs=0.03)


def test_same_seed_same_noise():
    a, g, r = _still(500)
    m = PRESETS["automotive"]
    first = apply_imu_noise(m, a, g, r, DT, seed=7)
    again = apply_imu_noise(m, a, g, r, DT, seed=7)
    other = apply_imu_noise(m, a, g, r, DT, seed=8)
    assert all(np.array_equal(x, y) for x, y in zip(first, again))
    assert not np.array_equal(first[0], other[0])
