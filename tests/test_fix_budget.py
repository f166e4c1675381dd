"""taco_mav/evaluation/fix_budget.py: the Riccati bound equals a simulated Kalman filter's error; it moves the right
way with fix quality, spacing and latency; its command line (tools/fix_budget_bound.py) prints the table and names
bad input."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taco_mav.errors import UsageError
from taco_mav.evaluation import fix_budget as bound

TOOL = Path(__file__).resolve().parents[1] / "tools" / "fix_budget_bound.py"


def _simulated_rms(drift, sigma: float, period: float, latency: float, n: int, seed: int) -> float:
    """A seeded simulation of the model: a truth that drifts in fine steps, noisy fixes, a Kalman filter whose
    fix captured at t is used from t + latency on; the RMS of estimate minus truth over a fine grid."""
    rng = np.random.default_rng(seed)
    dt = period / 40
    steps = n * 40
    b = np.cumsum(drift.q_bias * math.sqrt(dt) * rng.normal(size=steps))
    v = np.cumsum((b + drift.q_speed / math.sqrt(dt) * rng.normal(size=steps)) * dt)
    p = np.cumsum(v * dt)
    phi, q = bound.transition(drift, period)
    x, P, h = np.zeros(3), np.diag([100.0, 1.0, 0.01]), np.array([1.0, 0.0, 0.0])
    post = []
    for k in range(n):
        if k:
            x, P = phi @ x, phi @ P @ phi.T + q
        z = p[k * 40] + sigma * rng.normal()
        K = P @ h / (P[0, 0] + sigma**2)
        x, P = x + K * (z - x[0]), P - np.outer(K, h @ P)
        post.append(x)
    errs = []
    for i in range(100 * 40, steps):
        j = int(math.floor((i * dt - latency) / period + 1e-9))  # the newest fix in use at this time
        age = i * dt - j * period
        est = post[j][0] + post[j][1] * age + 0.5 * post[j][2] * age * age
        errs.append(est - p[i])
    return float(np.sqrt(np.mean(np.square(errs))))


@pytest.mark.parametrize("latency", [0.0, 1.0, 5.0])
def test_the_riccati_bound_is_the_error_of_a_simulated_kalman_filter(latency):
    drift = bound.Drift(0.05, 0.002)
    sigma, period, n = 0.6, 4.0, 1500
    predicted = bound.along_track_rms(drift, np.full(n, sigma), period, latency)
    simulated = _simulated_rms(drift, sigma, period, latency, n, seed=3)
    assert simulated == pytest.approx(predicted, rel=0.08)


def test_the_bound_grows_with_fix_error_spacing_and_latency_and_knows_each_fixs_sigma():
    drift = bound.Drift(0.035)
    rms = lambda sigma, period, lat=1.0: bound.along_track_rms(drift, np.full(400, sigma), period, lat)  # noqa: E731
    assert rms(0.15, 4.0) < rms(0.8, 4.0) < rms(0.8, 5.0) < rms(0.8, 5.0, 2.0)
    assert rms(0.0, 4.0, 0.0) > 0.0  # exact fixes still leave the drift between them
    # a mixture with one component is that sigma; a filter told each fix's sigma beats one told their RMS
    mix = [(0.5, 0.2), (0.5, 1.4)]
    drawn = bound.fix_sigmas(mix, 2000, seed=1)
    assert np.array_equal(drawn, bound.fix_sigmas(mix, 2000, seed=1))
    assert set(np.unique(drawn)) == {0.2, 1.4} and 0.45 < np.mean(drawn == 0.2) < 0.55
    assert np.all(bound.fix_sigmas([(1.0, 0.8)], 60, seed=0) == 0.8)
    rms_of_mix = math.sqrt(np.mean(drawn**2))
    assert bound.along_track_rms(drift, drawn, 4.0, 1.0) < rms(rms_of_mix, 4.0)


def test_the_table_has_a_cell_per_spacing_and_latency_and_names_bad_input():
    table = bound.budget_table(bound.Drift(0.035), [(1.0, 0.8)], [25.0, 40.0], 8.2, [0.0, 1.0], fixes=300)
    assert table.shape == (2, 2)
    sigmas = np.full(300 + bound.BURN_IN, 0.8)
    assert table[1, 1] == bound.along_track_rms(bound.Drift(0.035), sigmas, 40.0 / 8.2, 1.0)
    assert table[0, 0] < table[1, 0] < table[1, 1]  # wider spacing, later answers: a larger error
    assert bound.parse_mix("0.5:0.2,2:1.4") == [(0.5, 0.2), (2.0, 1.4)]
    for bad in ("0.5:0.2,oops", "0:1", "1:-0.1"):
        with pytest.raises(UsageError, match="--fix-mix item"):
            bound.parse_mix(bad)
    with pytest.raises(UsageError, match="spacings > 0"):
        bound.budget_table(bound.Drift(0.035), [(1.0, 0.8)], [40.0, 0.0], 8.2, [0.0], fixes=300)
    with pytest.raises(ValueError, match="more than 50 fixes"):
        bound.along_track_rms(bound.Drift(0.05), np.full(10, 0.5), 4.0)


def _tool(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(TOOL), *args], capture_output=True, text=True, timeout=120)


def test_the_command_prints_fixes_per_km_and_names_bad_input():
    run = _tool("--q-speed", "0.035", "--fix-sigma", "0.8", "--spacings", "25,40", "--latencies", "0,1",
                "--fixes", "300")
    assert run.returncode == 0, run.stderr
    out = run.stdout.splitlines()
    assert out[1].split() == ["spacing", "m", "fixes/km", "latency", "0", "s", "latency", "1", "s"]
    row40 = out[3].split()
    assert row40[:2] == ["40.0", "25.0"] and float(row40[2]) < float(row40[3])
    expected = bound.budget_table(bound.Drift(0.035), [(1.0, 0.8)], [40.0], 8.2, [0.0, 1.0], fixes=300)[0]
    assert [float(c) for c in row40[2:]] == pytest.approx(expected, abs=5e-4)
    run = _tool("--q-speed", "0.035", "--fix-mix", "0.5:0.2,oops", "--fixes", "300")
    assert run.returncode == 2 and "--fix-mix item 'oops'" in run.stderr
    run = _tool("--q-speed", "0.035", "--fix-sigma", "0.8", "--spacings", "40,0", "--fixes", "300")
    assert run.returncode == 2 and "spacings > 0" in run.stderr
