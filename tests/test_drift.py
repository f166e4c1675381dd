"""Dead-reckoning drift: recovered from a drive with known noise processes, measured on a real KITTI drive and
a real tlog, compared with a profile's process noise, and reported through `taco-mav drift`."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from taco_mav.config import load_profile, replace_in
from taco_mav.datasets.base import GroundTruth, ImuStream
from taco_mav.datasets.synthetic.imu_model import gauss_markov
from taco_mav.errors import DataError
from taco_mav.evaluation.drift import heading_model_std, measure_drift, report_text, speed_model_std

G = 9.80665


@dataclass
class KnownDrive:
    name: str
    imu: ImuStream
    truth: GroundTruth


def known_drive(duration_s: float = 1500.0, rate_hz: float = 10.0, q_speed: float = 0.05, beta: float = 0.01,
                tau_s: float = 30.0, q_theta: float = 0.001, offset: float = 0.0, seed: int = 1) -> KnownDrive:
    """A weaving drive at 8-12 m/s whose forward accelerometer has white noise of density q_speed
    (m/s)/sqrt(s) and whose compass reads the truth plus a Gauss-Markov bias (beta rad, tau_s) plus a random
    walk (q_theta rad/sqrt(s)) plus a constant `offset` (rad); everything else exact."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz) + 1
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    v = 10.0 + 2.0 * np.sin(2 * np.pi * t / 60.0)
    w = 0.05 * np.sin(2 * np.pi * t / 45.0)
    th = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)])
    mid, step = th[:-1] + 0.5 * np.diff(th), 0.5 * (v[1:] + v[:-1]) * dt
    xy = np.zeros((n, 2))
    xy[1:, 0], xy[1:, 1] = np.cumsum(step * np.cos(mid)), np.cumsum(step * np.sin(mid))
    a = np.gradient(v, dt) + rng.standard_normal(n) * q_speed / math.sqrt(dt)
    bias = gauss_markov(rng, n, dt, beta, tau_s, dims=1)[:, 0]
    err = offset + bias + np.cumsum(rng.standard_normal(n) * q_theta * math.sqrt(dt))
    yaw = np.angle(np.exp(1j * (np.pi / 2 - th - err)))  # NED yaw; ENU heading error = +err
    imu = ImuStream(t, np.c_[a, np.zeros(n), np.full(n, -G)], np.zeros((n, 3)), np.c_[np.zeros((n, 2)), yaw])
    return KnownDrive("known", imu, GroundTruth(t, xy, np.angle(np.exp(1j * th))))


def test_known_noise_is_recovered() -> None:
    r = measure_drift(known_drive())
    assert r.q_speed_mps == pytest.approx(0.05, rel=0.15)
    assert r.heading_measurable and r.notes == []
    # the heading fit reproduces the true model's growth over the horizons between fixes (RW and GM trade off)
    h = np.array([2.0, 5.0, 10.0, 20.0])
    true = heading_model_std(h, 0.001, 0.01, 30.0)
    fit = heading_model_std(h, r.q_theta_rad, r.compass_bias_sigma_rad, r.compass_bias_tau_s)
    assert np.allclose(fit, true, rtol=0.2)
    assert np.allclose(r.speed_rms_mps[:6], speed_model_std(np.array(r.horizons_s[:6]), 0.05, 0.0), rtol=0.2)
    mounted = measure_drift(known_drive(q_theta=0.0, offset=0.05))
    assert mounted.heading_offset_rad == pytest.approx(0.05, abs=0.005)  # a constant offset is reported, not fitted
    assert mounted.compass_bias_sigma_rad < 0.02
    assert set(r.plus_values()) >= {"q_speed_mps", "q_theta_rad"}


def test_verdicts_against_a_profile() -> None:
    r = measure_drift(known_drive(duration_s=600.0))
    plus = load_profile("synthetic").plus
    text = report_text(r, plus, "synthetic")
    assert "speed: profile 'synthetic' covers the measured drift" in text
    tight = replace_in(replace_in(load_profile("synthetic"), "plus.q_speed_mps", 0.01), "plus.q_bias_mps2", 0.0)
    text = report_text(r, tight.plus, "tight")
    assert "speed: profile 'tight' is OPTIMISTIC" in text
    assert f"  q_speed_mps: {r.plus_values()['q_speed_mps']:g}  # 0.01" in text


def test_kitti_drive(kitti_root: Path) -> None:
    from taco_mav.datasets.kitti import load_sequence

    if not (kitti_root / "2011_09_30").is_dir():
        pytest.skip("KITTI 2011_09_30 absent")
    r = measure_drift(load_sequence(kitti_root, "05"))
    assert not r.heading_measurable and "q_theta_rad" not in r.plus_values()  # OXTS yaw is both compass and truth
    assert 0.02 < r.q_speed_mps < 0.08  # an RT3003 at 10 Hz
    five = r.horizons_s.index(5.0)
    assert 0.1 < r.along_rms_m[five] < 0.6 and r.cross_rms_m[five] < 0.4
    assert r.speed_rms_mps[five] < speed_model_std(np.array([5.0]), 0.2, 0.005)[0]  # the kitti profile covers it


def test_too_short_is_a_data_error() -> None:
    with pytest.raises(DataError, match="known: fewer than 3 horizons"):
        measure_drift(known_drive(duration_s=2.0))


def test_cli_drift_on_a_tlog(tmp_path: Path) -> None:
    from taco_mav.cli import main
    from taco_mav.reliability.soak import circle_drive
    from tests.sim_helpers import write_tlog

    d = circle_drive(90.0, rate_hz=10.0, radius_m=150.0, speed_mps=8.0)
    rng = np.random.default_rng(3)
    d.accel_frd[:, 0] += rng.standard_normal(len(d)) * 0.05 / math.sqrt(0.1)  # 0.05 (m/s)/sqrt(s)
    tlog = write_tlog(tmp_path / "rover.tlog", d)
    out = tmp_path / "drift.json"
    assert main(["drift", "-q", "--tlog", str(tlog), "--profile", "ardupilot_rover", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    (rep,) = doc["drives"]
    assert rep["drive"] == "rover" and doc["profile"] == "ardupilot_rover"
    assert rep["q_speed_mps"] == pytest.approx(0.05, rel=0.3)
    assert rep["plus"]["q_speed_mps"] == pytest.approx(rep["q_speed_mps"], rel=0.05)
