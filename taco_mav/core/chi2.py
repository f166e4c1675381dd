"""Chi-square quantiles of even degrees of freedom, for the live daemon's statistical tests (pure maths).

scipy has them (`scipy.stats.chi2.isf`, `scipy.special.chdtri`), but scipy.special (with scipy.fft, which the
matcher does not use either) costs a companion computer 8 MB of its 250 MB budget (docs/companion.md), and the
daemon needs nothing else from it (the filter's kernels take only scipy.linalg's LAPACK). An even number
of degrees of freedom, 2 n (n 2-dof innovations, the only kind the daemon tests), has a closed form: a chi-square
of 2 n degrees exceeds x exactly when a Poisson count of mean x / 2 is at most n - 1,

    P(chi2(2 n) > x) = exp(-x / 2) sum_{k < n} (x / 2)^k / k!,

which is solved for x by Newton's method kept inside a bracket. Agrees with scipy to 1e-10 relative
(tests/test_chi2.py).
"""

from __future__ import annotations

import math
from statistics import NormalDist

__all__ = ["chi2_isf_even"]

_MAX_ITER = 200


def _log_tail(lam: float, n: int) -> tuple[float, float]:
    """(log P(Poisson(lam) <= n - 1), log P(Poisson(lam) = n - 1)), lam > 0."""
    logs = [k * math.log(lam) - lam - math.lgamma(k + 1.0) for k in range(n)]
    top = max(logs)
    return top + math.log(math.fsum(math.exp(v - top) for v in logs)), logs[-1]


def chi2_isf_even(dof: int, tail: float) -> float:
    """x with P(chi2(dof) > x) = tail, for an even dof >= 2 and 0 < tail < 1 (scipy's chi2.isf(tail, dof))."""
    if dof < 2 or dof % 2 or not 0.0 < tail < 1.0:
        raise ValueError(f"chi2_isf_even: dof must be even and >= 2, 0 < tail < 1; got {dof}, {tail}")
    n = dof // 2
    target = math.log(tail)
    # Wilson-Hilferty's normal approximation as the first guess, then a bracket [lo, hi] in lam = x / 2
    z = NormalDist().inv_cdf(1.0 - tail)
    c = 2.0 / (9.0 * dof)
    lam = max(0.5 * dof * max(1.0 - c + z * math.sqrt(c), 0.05) ** 3, 1e-12)
    lo, hi = 0.0, math.inf
    for _ in range(_MAX_ITER):
        log_sf, log_pmf = _log_tail(lam, n)
        if log_sf > target:
            lo = lam
        else:
            hi = lam
        # d log P / d lam = -pmf(n - 1) / P: Newton on the log tail, bisection where it leaves the bracket
        step = (log_sf - target) * math.exp(log_sf - log_pmf)
        nxt = lam + step
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi) if math.isfinite(hi) else 2.0 * lam
        if abs(nxt - lam) <= 1e-15 * lam:
            return 2.0 * nxt
        lam = nxt
    return 2.0 * lam
