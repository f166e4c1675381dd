"""Fix-budget bound: the along-track error an optimal filter would reach with fixes of a given quality at a given
spacing, when the IMU's speed error drifts as `taco-mav drift` measures. It answers "can any estimator meet this
accuracy with these fixes at this budget?" before one tunes the real filter.

    python tools/fix_budget_bound.py --q-speed 0.035 --fix-sigma 0.80 --spacings 40 --speed-mps 8.2 --latencies 1
    python tools/fix_budget_bound.py --q-speed 0.035 --fix-mix 0.19:1.38,0.26:0.79,0.42:0.42,0.13:0.24 \\
        --spacings 20,25,33,40 --latencies 0,1

Model (along track only, relative to dead reckoning; metres, seconds):
- state (p, v, b): position error, speed error, forward accelerometer bias; dp/dt = v, dv/dt = b + w_v,
  db/dt = w_b, with white w_v of density q_speed^2 ((m/s)^2/s) and w_b of density q_bias^2 ((m/s^2)^2/s);
  `taco-mav drift` fits both on a drive with ground truth.
- a fix every spacing/speed seconds measures p with a known 1-sigma: one value (--fix-sigma, e.g. eval's
  `fix_error_along_rms_m`) or drawn per fix from a mixture of shares and sigmas (--fix-mix, e.g. per band of w),
  with a seed; the filter knows each fix's sigma, which no real filter does.
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

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm


@dataclass(frozen=True)
class Drift:
    """The IMU's along-track error growth: q_speed (m/s)/sqrt(s), q_bias (m/s^2)/sqrt(s)."""

    q_speed: float
    q_bias: float = 0.0


def transition(drift: Drift, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """State transition and process covariance of (p, v, b) over tau seconds (Van Loan's matrix exponential)."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    Qc = np.diag([0.0, drift.q_speed**2, drift.q_bias**2])
    M = np.zeros((6, 6))
    M[:3, :3], M[:3, 3:], M[3:, 3:] = -A, Qc, A.T
    E = expm(M * tau)
    phi = E[3:, 3:].T
    return phi, phi @ E[:3, 3:]


BURN_IN = 50  # fixes before the average starts: the wide initial covariance is forgotten by then


def along_track_rms(drift: Drift, sigmas: np.ndarray, period_s: float, latency_s: float = 0.0,
                    steps_per_period: int = 20, burn_in: int = BURN_IN) -> float:
    """Time-averaged RMS along-track error, metres, of the optimal filter with one fix every period_s seconds;
    sigmas: the 1-sigma of each fix in order, metres (the first burn_in are not averaged)."""
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


def fix_sigmas(mix: list[tuple[float, float]], n: int, seed: int) -> np.ndarray:
    """n fix sigmas (metres) drawn from a mixture of (share, sigma) pairs with a seeded generator."""
    shares = np.array([s for s, _ in mix], dtype=float)
    values = np.array([v for _, v in mix], dtype=float)
    return values[np.random.default_rng(seed).choice(len(mix), size=n, p=shares / shares.sum())]


def parse_mix(text: str) -> list[tuple[float, float]]:
    """'0.4:0.5,0.6:1.2' -> [(0.4, 0.5), (0.6, 1.2)]: shares (any positive scale) and 1-sigmas in metres."""
    out = []
    for item in text.split(","):
        share, sep, sigma = item.partition(":")
        try:
            pair = (float(share), float(sigma))
        except ValueError:
            pair = (-1.0, -1.0)
        if not sep or pair[0] <= 0.0 or pair[1] < 0.0:
            raise ValueError(f"--fix-mix item {item!r}: expected SHARE:SIGMA with SHARE > 0 and SIGMA >= 0 metres")
        out.append(pair)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--q-speed", type=float, required=True, help="speed-error random walk, (m/s)/sqrt(s)")
    ap.add_argument("--q-bias", type=float, default=0.0, help="accelerometer-bias random walk, (m/s^2)/sqrt(s)")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--fix-sigma", type=float, help="every fix's along-track 1-sigma, m")
    src.add_argument("--fix-mix", help="SHARE:SIGMA,...: fix sigmas (m) drawn per fix in these shares")
    ap.add_argument("--spacings", default="40", help="distances between fixes, m, e.g. 25,33,40 (default 40)")
    ap.add_argument("--speed-mps", type=float, default=8.2, help="mean speed, m/s (default 8.2, KITTI's)")
    ap.add_argument("--latencies", default="0", help="matcher latencies, s, e.g. 0,1 (default 0)")
    ap.add_argument("--fixes", type=int, default=2000, help="fixes averaged over (default 2000)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the --fix-mix draws (default 0)")
    a = ap.parse_args(argv)
    try:
        mix = parse_mix(a.fix_mix) if a.fix_mix else [(1.0, a.fix_sigma)]
        spacings = [float(s) for s in a.spacings.split(",")]
        latencies = [float(x) for x in a.latencies.split(",")]
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.q_speed < 0.0 or a.q_bias < 0.0 or a.speed_mps <= 0.0 or min(spacings) <= 0.0 or min(latencies) < 0.0:
        print("error: --q-speed and --q-bias must be >= 0, --speed-mps and spacings > 0, latencies >= 0",
              file=sys.stderr)
        return 2
    drift = Drift(a.q_speed, a.q_bias)
    sigmas = fix_sigmas(mix, a.fixes + BURN_IN, a.seed)
    print(f"along-track RMS error of the optimal filter, m (q_speed {a.q_speed}, q_bias {a.q_bias}, "
          f"{a.speed_mps} m/s, fix sigmas {', '.join(f'{s:g}:{v:g} m' for s, v in mix)})")
    print("spacing m  fixes/km  " + "  ".join(f"latency {lat:g} s" for lat in latencies))
    for spacing in spacings:
        cells = [along_track_rms(drift, sigmas, spacing / a.speed_mps, lat) for lat in latencies]
        print(f"{spacing:9.1f}  {1000.0 / spacing:8.1f}  " + "  ".join(f"{c:11.3f}" for c in cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
