"""Fix-budget bound: the along-track error an optimal filter would reach with fixes of a given quality at a given
spacing, when the IMU's speed error drifts as `taco-mav drift` measures. It answers "can any estimator meet this
accuracy with these fixes at this budget?" before one tunes the real filter (`tools/fix_budget_bound.py` is its
command line).

Model (along track only, relative to dead reckoning; metres, seconds):
- state (p, v, b): position error, speed error, forward accelerometer bias; dp/dt = v, dv/dt = b + w_v,
  db/dt = w_b, with white w_v of density q_speed^2 ((m/s)^2/s) and w_b of density q_bias^2 ((m/s^2)^2/s);
  `taco-mav drift` fits both on a drive with ground truth.
- a fix every spacing/speed seconds measures p with a known 1-sigma: one value (e.g. eval's
  `fix_error_along_rms_m`) or drawn per fix from a mixture of shares and sigmas (e.g. per band of w), with a
  seed; the filter knows each fix's sigma, which no real filter does.
- a fix captured at t is applied at t + latency and replayed exactly, as the Localiser does; until then the
  estimate is the previous fix's, propagated.

The Kalman filter is the optimal estimator for this linear-Gaussian model, and its covariance does not depend on
the measured values, so the bound is its time-averaged position variance (a Riccati recursion, not a
simulation). It is a model, so check it against a measured run before trusting it: `taco-mav drift` fits
q_speed on the truth's speed, whose noise it counts as drift (0.046-0.059 on KITTI 04-09, an upper bound); on
KITTI OXTS q_speed 0.035 reproduces both eval's same-area along-track error (`ate_along_m` 0.35 m from fixes
0.15 m along, 25/km, 1 s late; model 0.35 m) and the cross-area one (0.87 m from 0.80 m fixes; model 0.91 m).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from taco_mav.errors import UsageError

__all__ = ["BURN_IN", "Drift", "along_track_rms", "budget_table", "fix_sigmas", "parse_mix", "transition"]

BURN_IN = 50  # fixes before the average starts: the wide initial covariance is forgotten by then


@dataclass(frozen=True)
class Drift:
    """The IMU's along-track error growth: q_speed (m/s)/sqrt(s), q_bias (m/s^2)/sqrt(s)."""

    q_speed: float
    q_bias: float = 0.0


def transition(drift: Drift, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """State transition (3, 3) and process covariance (3, 3) of (p, v, b) over tau seconds (Van Loan's matrix
    exponential); p in metres, v in m/s, b in m/s^2."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    Qc = np.diag([0.0, drift.q_speed**2, drift.q_bias**2])
    M = np.zeros((6, 6))
    M[:3, :3], M[:3, 3:], M[3:, 3:] = -A, Qc, A.T
    E = expm(M * tau)
    phi = E[3:, 3:].T
    return phi, phi @ E[:3, 3:]


def along_track_rms(drift: Drift, sigmas: np.ndarray, period_s: float, latency_s: float = 0.0,
                    steps_per_period: int = 20, burn_in: int = BURN_IN) -> float:
    """Time-averaged RMS along-track error, metres, of the optimal filter with one fix every period_s seconds,
    each applied latency_s seconds after its capture; sigmas: the 1-sigma of each fix in order, metres, shape
    (N,) (the first burn_in are not averaged). ValueError for a period <= 0, a latency < 0 or too few fixes."""
    if period_s <= 0.0 or latency_s < 0.0 or len(sigmas) <= burn_in:
        raise ValueError(f"need a positive period, a latency >= 0 and more than {burn_in} fixes")
    taus = (np.arange(steps_per_period) + 0.5) * period_s / steps_per_period  # mid-points within a period
    P = np.diag([100.0, 1.0, 0.01])  # wide start, forgotten during the burn-in
    posteriors = []
    h = np.array([1.0, 0.0, 0.0])
    step = transition(drift, period_s)
    for k, sigma in enumerate(sigmas):
        if k:
            P = step[0] @ P @ step[0].T + step[1]
        S = P[0, 0] + sigma * sigma
        K = P @ h / S
        P = P - np.outer(K, h @ P)
        posteriors.append(P)
    lag = int(math.floor(latency_s / period_s))  # whole periods the answer is late by
    frac = latency_s - lag * period_s
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    total, count = 0.0, 0
    for k in range(burn_in + lag + 1, len(sigmas)):
        for tau in taus:  # time since capture k
            j, age = (k - lag, tau + lag * period_s) if tau >= frac else (k - lag - 1, tau + (lag + 1) * period_s)
            phi, q = cache.setdefault(age, transition(drift, age))
            total += float((phi @ posteriors[j] @ phi.T + q)[0, 0])
            count += 1
    return math.sqrt(total / count)


def fix_sigmas(mix: Sequence[tuple[float, float]], n: int, seed: int) -> np.ndarray:
    """n fix sigmas (metres), shape (n,), drawn from a mixture of (share, sigma) pairs with a seeded generator."""
    shares = np.array([s for s, _ in mix], dtype=float)
    values = np.array([v for _, v in mix], dtype=float)
    return values[np.random.default_rng(seed).choice(len(mix), size=n, p=shares / shares.sum())]


def parse_mix(text: str) -> list[tuple[float, float]]:
    """'0.4:0.5,0.6:1.2' -> [(0.4, 0.5), (0.6, 1.2)]: shares (any positive scale) and 1-sigmas in metres.
    UsageError naming --fix-mix and the item that is not SHARE:SIGMA."""
    out = []
    for item in text.split(","):
        share, sep, sigma = item.partition(":")
        try:
            pair = (float(share), float(sigma))
        except ValueError:
            pair = (-1.0, -1.0)
        if not sep or pair[0] <= 0.0 or pair[1] < 0.0:
            raise UsageError(f"--fix-mix item {item!r}: expected SHARE:SIGMA with SHARE > 0 and SIGMA >= 0 metres")
        out.append(pair)
    return out


def budget_table(drift: Drift, mix: Sequence[tuple[float, float]], spacings_m: Sequence[float], speed_mps: float,
                 latencies_s: Sequence[float], fixes: int = 2000, seed: int = 0) -> np.ndarray:
    """The bound for every fix spacing (metres) and latency (seconds) at speed_mps: RMS along-track error,
    metres, shape (len(spacings_m), len(latencies_s)). The fix sigmas (fixes + BURN_IN of them) are drawn once
    from `mix` with `seed` and shared by every cell. UsageError for a negative drift, a speed or spacing <= 0
    or a latency < 0."""
    if (drift.q_speed < 0.0 or drift.q_bias < 0.0 or speed_mps <= 0.0 or min(spacings_m) <= 0.0
            or min(latencies_s) < 0.0):
        raise UsageError("--q-speed and --q-bias must be >= 0, --speed-mps and spacings > 0, latencies >= 0")
    sigmas = fix_sigmas(mix, fixes + BURN_IN, seed)
    return np.array([[along_track_rms(drift, sigmas, spacing / speed_mps, lat) for lat in latencies_s]
                     for spacing in spacings_m])
