"""Compiled (numba) kernels for the planar UKF's per-frame predict and linear updates.

Why compiled: a 3- to 6-state filter is microseconds of arithmetic, but through filterpy and small numpy calls
each predict cost ~100 us of Python overhead (sigma points, a Python loop over the residuals, a dozen tiny array
allocations). numba compiles the whole step into one call.

Why bit-for-bit: with the paper's alpha = 1e-3 the centre sigma point weighs about -1e6, so the unscented
transform cancels ~6 digits and amplifies any change of rounding (a different summation order moves the
KITTI tracks by ~1e-6 m and the smoothed paper-mode track by ~5e-4 m). These kernels therefore do *exactly*
the operations of the reference (filterpy's `UnscentedKalmanFilter.predict` with `MerweScaledSigmaPoints`,
and `ukf.joseph_update_reference`), in the same order: element-wise arithmetic is IEEE double without FMA
contraction (numba's default), transcendental functions call the same libm as Python's `math`, and every
reduction that numpy hands to BLAS/LAPACK (np.dot, np.linalg.solve, the Cholesky factor, eigvalsh) goes through
numba's np.dot / np.linalg.*, which call scipy's bundled OpenBLAS: the same kernel code as numpy's (checked bit
for bit on this stack; a BLAS build that differed would show in the tests, not silently). The one shortcut, the
positive-definiteness test of `sym_pd`, only decides what LAPACK's eigvalsh would decide (see `_clearly_above`).
`tests/test_ukf_kernels.py` checks equality with filterpy and with the numpy references on random inputs.

`cache=True` writes the compiled code beside this module (__pycache__, or numba's user cache for a read-only
install), so only the first run after an install or an edit pays the JIT cost (~10 s on a quiet machine, about a
minute on a busy 2-core one); `warm_up()` compiles or loads every kernel (the bench calls it before timing, a
service may call it at start-up).

Frames and units as in ukf.py: x = [x m, y m, theta rad (ENU), (dv m/s, b m/s^2, (beta rad))].
"""

from __future__ import annotations

import logging
import math

import numba
import numpy as np

log = logging.getLogger(__name__)


def _probe() -> int:
    return 0


def _cache_usable() -> bool:
    """Whether numba finds a writable cache folder for this module (its __pycache__, NUMBA_CACHE_DIR or the
    user's cache). Without one, numba raises at decoration time; a read-only install in a service without a
    home folder then compiles at every start instead of failing to import."""
    try:
        numba.njit(cache=True)(_probe)
    except RuntimeError as exc:
        log.warning("numba has no writable cache folder (%s): the UKF kernels compile at every start "
                    "(set NUMBA_CACHE_DIR to a writable folder to keep them)", exc)
        return False
    return True


_JIT = dict(cache=_cache_usable(), nogil=True)


@numba.njit(**_JIT)
def wrap(a: float) -> float:
    """Wrap an angle to (-pi, pi], radians (atan2(sin a, cos a), as preintegration.wrap_angle)."""
    return math.atan2(math.sin(a), math.cos(a))


@numba.njit(**_JIT)
def _motion(s: np.ndarray, out: np.ndarray, dt: float, d_fwd: float, d_left: float, d_theta: float,
            bias_decay: float) -> None:
    """ukf._motion for one sigma point `s`, written into `out` (same operations, same order)."""
    n = s.shape[0]
    if n >= 5:
        dv = s[3]
        b = s[4]
        d_fwd = d_fwd + dv * dt - 0.5 * b * dt * dt
    c = math.cos(s[2])
    sn = math.sin(s[2])
    out[0] = s[0] + c * d_fwd - sn * d_left
    out[1] = s[1] + sn * d_fwd + c * d_left
    out[2] = s[2] + d_theta
    if n >= 5:
        out[3] = s[3] - s[4] * dt
        out[4] = s[4]
    if n >= 6:
        out[5] = s[5] * bias_decay
    for j in range(6, n):  # the map's offset (8 states) is constant
        out[j] = s[j]


@numba.njit(**_JIT)
def _clearly_above(S: np.ndarray, floor: float) -> bool:
    """True when every eigenvalue of the symmetric S is certainly >= floor, also as LAPACK's eigvalsh computes
    it: the Cholesky factorisation of S - m I succeeds with m = floor + 200 n eps trace(S), a margin far above
    both the factorisation's backward error and eigvalsh's (each a few n eps ||S||). False means "ask
    eigvalsh" (a sufficient test only: it decides nothing by itself)."""
    n = S.shape[0]
    tr = 0.0
    for i in range(n):
        tr += abs(S[i, i])
    m = floor + 200.0 * n * 2.220446049250313e-16 * tr
    L = np.zeros((n, n))
    for j in range(n):
        d = S[j, j] - m
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = S[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    return True


@numba.njit(**_JIT)
def sym_pd(P: np.ndarray, floor: float) -> tuple[np.ndarray, bool]:
    """(S, ok): S = (P + P^T) / 2 and whether ukf.nearest_pd would keep it as it is (Sylvester's criterion with a
    margin for 3x3, else the smallest eigenvalue by LAPACK's eigvalsh >= floor, which a Cholesky test with a wide
    margin settles first in the usual case). When not ok the caller lifts the eigenvalues."""
    S = 0.5 * (P + P.T)
    if S.shape[0] == 3:
        a, b, c = S[0, 0], S[0, 1], S[0, 2]
        d, e = S[1, 1], S[1, 2]
        f = S[2, 2]
        m2 = a * d - b * b
        m3 = a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d)
        return S, (a > floor and m2 > floor * a and m3 > floor * m2)
    if _clearly_above(S, floor):
        return S, True
    return S, bool(np.linalg.eigvalsh(S).min() >= floor)


@numba.njit(**_JIT)
def predict(x: np.ndarray, P: np.ndarray, Q: np.ndarray, lam_n: float, Wm: np.ndarray, Wc: np.ndarray, dt: float,
            d_fwd: float, d_left: float, d_theta: float, bias_decay: float,
            floor: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """One unscented predict (van der Merwe sigma points from the upper Cholesky factor of lam_n P, the
    body-frame motion model, the weighted mean and the wrapped-residual covariance plus Q), then theta wrapped
    and P symmetrised. Returns (x, P, ok) with ok as in `sym_pd`. Raises LinAlgError when lam_n P is not
    positive definite (as scipy's cholesky does)."""
    n = x.shape[0]
    U = np.linalg.cholesky(lam_n * P).T  # rows of the upper factor, as scipy.linalg.cholesky(lower=False)
    k = 2 * n + 1
    sig = np.empty((k, n))
    sig[0] = x
    for i in range(n):
        for j in range(n):
            sig[i + 1, j] = x[j] + U[i, j]  # filterpy: subtract(x, -U[i]) = _residual_x(x, -U[i])
            sig[n + i + 1, j] = x[j] - U[i, j]
        sig[i + 1, 2] = wrap(sig[i + 1, 2])
        sig[n + i + 1, 2] = wrap(sig[n + i + 1, 2])
    f = np.empty((k, n))
    for i in range(k):
        _motion(sig[i], f[i], dt, d_fwd, d_left, d_theta, bias_decay)
    xm = np.dot(Wm, f)
    Pn = np.zeros((n, n))
    y = np.empty(n)
    for i in range(k):
        for j in range(n):
            y[j] = f[i, j] - xm[j]
        y[2] = wrap(y[2])
        w = Wc[i]
        for r in range(n):
            for c in range(n):
                Pn[r, c] += w * (y[r] * y[c])
    Pn += Q
    xm[2] = wrap(xm[2])
    S, ok = sym_pd(Pn, floor)
    return xm, S, ok


@numba.njit(**_JIT)
def joseph(P: np.ndarray, H: np.ndarray, innovation: np.ndarray, R: np.ndarray,
           floor: float) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """ukf.joseph_update_reference, compiled, less the state step: (K^T, S, NIS, ok) with K^T the transposed
    gain (m x n, C-ordered, so that its .T is F-ordered as numpy's K), S the symmetrised Joseph-form covariance and
    ok as in `sym_pd` (when not ok the caller lifts its eigenvalues). The caller adds K @ innovation in numpy: for an
    F-ordered K with 4 columns numpy's gemv sums in an order numba's does not reproduce."""
    HP = np.dot(H, P)
    S = np.dot(HP, H.T) + R
    S = 0.5 * (S + S.T)
    Kt = np.ascontiguousarray(np.linalg.solve(S, HP))
    K = Kt.T
    I_KH = np.eye(P.shape[0]) - np.dot(K, H)
    P_new = np.dot(np.dot(I_KH, P), I_KH.T) + np.dot(np.dot(K, R), K.T)
    nis = np.dot(innovation, np.linalg.solve(S, innovation))
    Ps, ok = sym_pd(P_new, floor)
    return Kt, Ps, nis, ok


@numba.njit(**_JIT)
def scalar_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, z: float, variance: float, col: int,
                  floor: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """A one-row update as PlanarUkf did it through `joseph_update_reference`: a compass heading (col < 0:
    innovation wrap(z - H x), H x the BLAS dot numpy used) or a direct measurement of state `col` (innovation
    z - x[col]), against variance R, then theta wrapped. Returns (x, P, ok) with ok as in `sym_pd`. With one
    measurement row numpy's K @ y is K * y per element (every summation order gives the same single product),
    so the state step is done here too."""
    y = np.empty(1)
    if col < 0:
        y[0] = wrap(z - np.dot(H[0], x))
    else:
        y[0] = z - x[col]
    R = np.empty((1, 1))
    R[0, 0] = variance
    Kt, Ps, nis, ok = joseph(P, H, y, R, floor)
    x_new = x + Kt[0] * y[0]
    x_new[2] = wrap(x_new[2])
    return x_new, Ps, ok


@numba.njit(**_JIT)
def process_noise(theta: float, sigma_fwd: float, sigma_lat: float, sigma_theta: float, scale: float) -> np.ndarray:
    """ukf.process_noise compiled (with scale = dt / frame_dt)."""
    Q = np.zeros((3, 3))
    Q[:2, :2] = fix_covariance(theta, sigma_fwd, sigma_lat) * scale
    Q[2, 2] = sigma_theta * sigma_theta * scale
    return Q


@numba.njit(**_JIT)
def process_noise_plus(theta: float, dt: float, distance: float, n: int, q55: float, q_pos: float, q_fwd: float,
                       q_lat: float, q_theta: float, q_speed: float, q_bias: float) -> np.ndarray:
    """plus.process_noise_plus compiled (q55: the compass-bias entry, computed by the caller)."""
    Q = np.zeros((n, n))
    if n >= 6:
        Q[5, 5] = q55
    rw = q_pos * q_pos * dt
    fc = fix_covariance(theta, q_fwd * distance, q_lat * distance)
    for i in range(2):
        for j in range(2):
            Q[i, j] = fc[i, j] + rw * (1.0 if i == j else 0.0)  # + rw * np.eye(2), zeros included
    Q[2, 2] = q_theta * q_theta * dt
    Q[3, 3] = q_speed * q_speed * dt
    Q[4, 4] = q_bias * q_bias * dt
    return Q


@numba.njit(**_JIT)
def horizontal_sigma(cov: np.ndarray) -> float:
    """types.horizontal_sigma compiled: sqrt of the largest eigenvalue of the 2x2 position block (the same
    LAPACK eigvalsh numpy calls), metres."""
    w = np.linalg.eigvalsh(np.ascontiguousarray(cov[:2, :2]))
    return np.sqrt(max(w.max(), 0.0))


@numba.njit(**_JIT)
def fix_covariance(theta: float, sigma_fwd: float, sigma_lat: float) -> np.ndarray:
    """ukf.fix_covariance compiled: Rot(theta) diag(sigma_fwd^2, sigma_lat^2) Rot(theta)^T, m^2."""
    c = math.cos(theta)
    s = math.sin(theta)
    Rot = np.empty((2, 2))
    Rot[0, 0], Rot[0, 1], Rot[1, 0], Rot[1, 1] = c, -s, s, c
    D = np.zeros((2, 2))
    D[0, 0] = sigma_fwd * sigma_fwd
    D[1, 1] = sigma_lat * sigma_lat
    return np.dot(np.dot(Rot, D), Rot.T)


def warm_up() -> None:
    """Compile (or load from the cache) every kernel for the 3-, 5- and 6-state filters."""
    for n in (3, 5, 6):
        x = np.zeros(n)
        P = np.eye(n)
        W = np.full(2 * n + 1, 0.1)
        predict(x, P, P.copy(), 1.0, W, W, 0.1, 0.0, 0.0, 0.0, 1.0, 1e-9)
        for m in range(1, min(n, 4) + 1):
            H = np.zeros((m, n))
            H[np.arange(m), np.arange(m)] = 1.0
            joseph(P, H, np.zeros(m), np.eye(m), 1e-9)
    fix_covariance(0.0, 1.0, 1.0)
    horizontal_sigma(np.eye(2))
    horizontal_sigma(np.eye(5)[:, :])
    process_noise(0.0, 1.0, 1.0, 0.1, 1.0)
    process_noise_plus(0.0, 0.1, 1.0, 6, 0.0, 0.1, 0.01, 0.01, 0.002, 0.2, 0.005)
    for n in (3, 5, 6):
        scalar_update(np.zeros(n), np.eye(n), np.eye(n)[2:3].copy(), 0.0, 1.0, -1, 1e-9)
    wrap(0.0)
