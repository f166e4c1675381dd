"""3-state UKF on (x, y, theta) with anisotropic CVGL noise (paper Sec. III-F); taco+ adds 2 or 3 states.

State: x, y ENU metres relative to the origin; theta ENU heading, radians. Predict propagates van der Merwe
sigma points (filterpy) through the body-frame rigid-motion model with a preintegrated increment
(forward, left, dtheta). Updates are linear (a position fix; a compass heading), so they are done as exact
Kalman updates in Joseph form rather than with filterpy's unscented update: with alpha = 1e-3 the centre
sigma point's weight is about -1e6, and once P is large (minutes without a fix) the unscented update's
cancellation loses positive definiteness. After every step P is symmetrised and, if needed, repaired to the
nearest positive-definite matrix (eigenvalue floor), so Cholesky in the next predict never fails.

Speed: predict and the updates run as compiled kernels (`ukf_kernels`, numba; through `kernels`,
which loads them compiled ahead of time, without numba, when `ukf_aot` built them) that do exactly the
operations of filterpy's predict and of `joseph_update_reference`, bit for bit; the filter keeps x and P as
plain arrays. The sigma-point weights are filterpy's `MerweScaledSigmaPoints` weights, computed here by the same
arithmetic (`merwe_weights`): importing filterpy.kalman loads scipy.stats, about 55 MB a companion computer's
daemon never otherwise uses (docs/companion.md); tests/test_ukf_kernels.py holds the filter to filterpy bit for bit.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from taco_mav.core import kernels as _k
from taco_mav.core.preintegration import wrap_angle as _wrap

if TYPE_CHECKING:
    from taco_mav.core.params import UkfParams

_EIG_FLOOR = 1e-9


def _motion(x: np.ndarray, dt: float, d_fwd: float = 0.0, d_left: float = 0.0, d_theta: float = 0.0,
            bias_decay: float = 1.0) -> np.ndarray:
    """Body-frame rigid motion (Sec. III-F): rotate (forward, left) by theta, add dtheta (no wrap here).
    With the taco+ states (x[3] = speed error dv m/s, x[4] = accelerometer bias b m/s^2) the forward step
    gains dv dt - b dt^2 / 2 and dv loses b dt; the optional x[5] (compass bias, rad, first-order
    Gauss-Markov) decays by `bias_decay` = exp(-dt / tau); the optional x[6:8] (the map's georeferencing
    offset, m: config map.georef_sigma_m) stay as they are."""
    if len(x) >= 5:
        dv, b = x[3], x[4]
        d_fwd = d_fwd + dv * dt - 0.5 * b * dt * dt
    c, s = math.cos(x[2]), math.sin(x[2])
    moved = [x[0] + c * d_fwd - s * d_left, x[1] + s * d_fwd + c * d_left, x[2] + d_theta]
    if len(x) >= 5:
        moved += [x[3] - x[4] * dt, x[4]]
    if len(x) >= 6:
        moved.append(x[5] * bias_decay)
    if len(x) == 8:
        moved += [x[6], x[7]]
    return np.array(moved)


def _residual_x(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a - b
    d[2] = _wrap(d[2])
    return d


def _leading_minors_positive(S: np.ndarray, floor: float) -> bool:
    """Sylvester's criterion with a margin, for the 2x2/3x3 matrices here (cheaper than an eigendecomposition)."""
    if S.shape == (3, 3):
        (a, b, c), (_, d, e), (_, _, f) = S.tolist()
        m2 = a * d - b * b
        m3 = a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d)
        return a > floor and m2 > floor * a and m3 > floor * m2
    return bool(np.linalg.eigvalsh(S).min() >= floor)


def nearest_pd(P: np.ndarray, floor: float = _EIG_FLOOR) -> np.ndarray:
    """Symmetrise P and lift any eigenvalue below `floor` to it (the nearest PD matrix in Frobenius norm)."""
    S = 0.5 * (P + P.T)
    if _leading_minors_positive(S, floor):
        return S
    return _lift(S, floor)


def _lift(S: np.ndarray, floor: float) -> np.ndarray:
    """Lift the eigenvalues of the symmetric S below `floor` to it."""
    w, V = np.linalg.eigh(S)
    w = np.maximum(w, floor)
    return (V * w) @ V.T


def joseph_update(x: np.ndarray, P: np.ndarray, H: np.ndarray, innovation: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Exact linear Kalman update in Joseph form. Returns (x, P, NIS) where NIS = y^T S^-1 y. Compiled; the
    same numbers as `joseph_update_reference`."""
    c = np.ascontiguousarray
    innovation = c(innovation, dtype=float)
    Kt, P_new, nis, ok = _k.joseph(c(P, dtype=float), c(H, dtype=float), innovation, c(R, dtype=float), _EIG_FLOOR)
    return x + Kt.T @ innovation, P_new if ok else _lift(P_new, _EIG_FLOOR), float(nis)


def joseph_update_reference(x: np.ndarray, P: np.ndarray, H: np.ndarray, innovation: np.ndarray,
                            R: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """`joseph_update` in plain numpy (the specification the compiled kernel is tested against)."""
    S = H @ P @ H.T + R
    S = 0.5 * (S + S.T)
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S symmetric)
    x_new = x + K @ innovation
    I_KH = np.eye(len(x)) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    nis = float(innovation @ np.linalg.solve(S, innovation))
    return x_new, nearest_pd(P_new), nis


def _rows(n: int, *cols: int) -> np.ndarray:
    """Measurement matrix picking state components `cols` of an n-state vector."""
    H = np.zeros((len(cols), n))
    H[np.arange(len(cols)), cols] = 1.0
    return H


def merwe_weights(n: int, alpha: float, beta: float, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """(Wm, Wc), each (2 n + 1,): van der Merwe's scaled sigma-point weights for the mean and the covariance of an
    n-state filter, by filterpy's arithmetic (MerweScaledSigmaPoints._compute_weights), to the bit."""
    lambda_ = alpha**2 * (n + kappa) - n
    c = 0.5 / (n + lambda_)
    Wc = np.full(2 * n + 1, c)
    Wm = np.full(2 * n + 1, c)
    Wc[0] = lambda_ / (n + lambda_) + (1 - alpha**2 + beta)
    Wm[0] = lambda_ / (n + lambda_)
    return Wm, Wc


class PlanarUkf:
    """The TACO filter. x: (3,) [x m, y m, theta rad]; P: (3, 3). taco+ passes a (5,) x0 that adds the
    forward speed error dv (m/s, true minus preintegrated) and the forward accelerometer bias b (m/s^2), or a
    (6,) x0 that also carries the compass bias beta (rad; the compass reads theta + beta), or an (8,) x0 that
    also carries the map's georeferencing offset (bx, by) m: a camera fix then measures position + offset."""

    def __init__(self, x0: np.ndarray, P0: np.ndarray, alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0) -> None:
        n = len(x0)
        if n not in (3, 5, 6, 8) or np.shape(P0) != (n, n):
            raise ValueError(f"PlanarUkf: state must be 3, 5, 6 or 8 long with a matching P, got {n} and "
                             f"{np.shape(P0)}")
        self._Wm, self._Wc = merwe_weights(n, alpha, beta, kappa)
        self._lam_n = (alpha**2 * (n + kappa) - n) + n  # filterpy: (lambda_ + n) scales P before the Cholesky
        self._x = np.asarray(x0, dtype=float).copy()
        self._P = nearest_pd(np.asarray(P0, dtype=float))
        self._h_pos, self._h_theta, self._h_true_theta = _rows(n, 0, 1), _rows(n, 2), _rows(n, 2)
        if n >= 6:
            self._h_theta[0, 5] = 1.0  # the compass reads theta + beta
        if n == 8:
            self._h_pos[0, 6] = self._h_pos[1, 7] = 1.0  # a map fix reads position + the map's offset
        self._h_speed = _rows(n, 3) if n >= 5 else None

    @property
    def x(self) -> np.ndarray:
        """The state (the live array: callers may adjust components in place)."""
        return self._x

    @property
    def P(self) -> np.ndarray:
        return self._P

    def get_state(self) -> tuple[np.ndarray, np.ndarray]:
        """A copy of (x, P) for the delayed-fix history."""
        return self._x.copy(), self._P.copy()

    def set_state(self, x: np.ndarray, P: np.ndarray) -> None:
        self._x = np.array(x, dtype=float)
        self._P = np.array(P, dtype=float)

    def predict(self, d_fwd: float, d_left: float, d_theta: float, Q: np.ndarray, dt: float = 0.1,
                bias_decay: float = 1.0) -> None:
        """Propagate by one body-frame increment (metres, metres, rad) over dt seconds with process noise Q
        (n x n; dt matters only for the taco+ speed states; bias_decay only for the compass bias)."""
        Q = np.ascontiguousarray(Q, dtype=float)
        args = (Q, self._lam_n, self._Wm, self._Wc, float(dt), float(d_fwd), float(d_left), float(d_theta),
                float(bias_decay), _EIG_FLOOR)
        try:
            x, P, ok = _k.predict(self._x, self._P, *args)
        except np.linalg.LinAlgError:
            self._P = nearest_pd(self._P, floor=1e-6)
            x, P, ok = _k.predict(self._x, self._P, *args)
        self._x, self._P = x, P if ok else _lift(P, _EIG_FLOOR)

    def _update(self, H: np.ndarray, innovation: np.ndarray, R: np.ndarray) -> float:
        Kt, P, nis, ok = _k.joseph(self._P, H, innovation, R, _EIG_FLOOR)
        x = self._x + Kt.T @ innovation
        x[2] = _k.wrap(x[2])
        self._x, self._P = x, P if ok else _lift(P, _EIG_FLOOR)
        return float(nis)

    def fix_prediction(self, x: np.ndarray | None = None, P: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """What a camera fix is expected to read for state (x, P) (default: the current one): (ENU m (2,), its
        covariance m^2 (2, 2)); the position, plus the map's offset with the 8-state filter."""
        x = self._x if x is None else x
        P = self._P if P is None else P
        if len(x) < 8:
            return x[:2].copy(), P[:2, :2].copy()
        H = self._h_pos
        return H @ x, H @ P @ H.T

    def update_position(self, z: np.ndarray, R: np.ndarray) -> float:
        """Camera fix z (ENU metres, (2,)) with covariance R (2x2): it reads the position (plus the map's
        offset with the 8-state filter). Returns the NIS."""
        innovation = np.asarray(z, dtype=float) - self.fix_prediction()[0]
        return self._update(self._h_pos, innovation, np.ascontiguousarray(R, dtype=float))

    def position_nis(self, z: np.ndarray, R: np.ndarray) -> float:
        """Normalised innovation squared of a camera fix, without applying it."""
        pred, S = self.fix_prediction()
        innovation = np.asarray(z, dtype=float) - pred
        return float(innovation @ np.linalg.solve(S + R, innovation))

    def update_speed_error(self, dv: float, sigma: float) -> None:
        """Measurement of the speed error state dv (m/s, 1-sigma m/s): a zero-velocity update measures
        dv = -(preintegrated speed). taco+ only."""
        if self._h_speed is None:
            raise ValueError("update_speed_error needs the 5-state (taco+) filter")
        self._scalar(self._h_speed, float(dv), sigma * sigma, 3)

    def update_heading(self, theta: float, sigma: float) -> None:
        """Compass heading measurement, ENU rad, 1-sigma rad (innovation wrapped to (-pi, pi]); with the
        compass-bias state the prediction is theta + beta."""
        self._scalar(self._h_theta, float(theta), sigma * sigma, -1)

    def update_true_heading(self, theta: float, sigma: float) -> None:
        """A measurement of the true heading theta itself (a camera fix's rotation), ENU rad, 1-sigma rad
        (innovation wrapped); unlike the compass it carries no compass bias."""
        self._scalar(self._h_true_theta, float(theta), sigma * sigma, -1)

    def _scalar(self, H: np.ndarray, z: float, variance: float, col: int) -> None:
        """One-row update with this variance: z a heading (col < 0: innovation wrap(z - H x)) or state `col`."""
        x, P, ok = _k.scalar_update(self._x, self._P, H, z, float(variance), col, _EIG_FLOOR)
        self._x, self._P = x, P if ok else _lift(P, _EIG_FLOOR)


def process_sigmas(epsilon: float, sigma_fwd_min: float = 1.0, sigma_fwd_k: float = 2.0, sigma_lat_min: float = 1.5,
                   sigma_lat_k: float = 0.3) -> tuple[float, float]:
    """Per-frame process sigmas, metres: sigma_fwd = max(1.0, 2.0 eps), sigma_lat = max(1.5, 0.3 eps)."""
    return max(sigma_fwd_min, sigma_fwd_k * epsilon), max(sigma_lat_min, sigma_lat_k * epsilon)


def process_noise(theta: float, sigma_fwd: float, sigma_lat: float, sigma_theta: float, dt: float, frame_dt: float) -> np.ndarray:
    """Q (3x3) for one predict: diag(sigma_fwd^2, sigma_lat^2, sigma_theta^2) per camera-rate frame
    (Sec. III-F) with the position block taken in the body frame (forward/lateral, as the names say) and
    rotated into ENU by theta, scaled by dt / frame_dt so the noise per second is the same at any rate."""
    return _k.process_noise(float(theta), float(sigma_fwd), float(sigma_lat), float(sigma_theta), dt / frame_dt)


def fix_sigmas(w: float, fwd_num: float = 1.5, fwd_min: float = 0.5, fwd_max: float = 8.0, lat_num: float = 3.0,
               lat_min: float = 1.0, lat_max: float = 12.0, anisotropic: bool = True) -> tuple[float, float]:
    """Per-fix body-frame sigmas, metres: clip(1.5/w, 0.5, 8), clip(3/w, 1, 12). Isotropic: both = mean."""
    w = max(float(w), 1e-6)
    s_fwd = min(max(fwd_num / w, fwd_min), fwd_max)
    s_lat = min(max(lat_num / w, lat_min), lat_max)
    if not anisotropic:
        s_fwd = s_lat = 0.5 * (s_fwd + s_lat)
    return s_fwd, s_lat


def fix_covariance(theta: float, sigma_fwd: float, sigma_lat: float) -> np.ndarray:
    """R_meas = Rot(theta) diag(sigma_fwd^2, sigma_lat^2) Rot(theta)^T, m^2 (ENU). Compiled
    (`ukf_kernels.fix_covariance`, the same numbers as `fix_covariance_reference`)."""
    return _k.fix_covariance(float(theta), float(sigma_fwd), float(sigma_lat))


def fix_covariance_reference(theta: float, sigma_fwd: float, sigma_lat: float) -> np.ndarray:
    """`fix_covariance` in plain numpy (the specification the kernel is tested against)."""
    c, s = math.cos(theta), math.sin(theta)
    Rot = np.array([[c, -s], [s, c]])
    return Rot @ np.diag([sigma_fwd * sigma_fwd, sigma_lat * sigma_lat]) @ Rot.T


def weight_sigmas(u: UkfParams, w: float, anisotropic: bool | None = None) -> tuple[float, float]:
    """Body-frame fix sigmas (forward, lateral), metres, from the match weight w (Sec. III-F) with the mapping of
    the UKF parameters `u`; anisotropic: None for u.anisotropic, False for both the mean of the two."""
    return fix_sigmas(w, u.fix_fwd_num, u.fix_fwd_min_m, u.fix_fwd_max_m, u.fix_lat_num, u.fix_lat_min_m,
                      u.fix_lat_max_m, u.anisotropic if anisotropic is None else anisotropic)
