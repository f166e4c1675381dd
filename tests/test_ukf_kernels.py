"""The compiled UKF path (core/ukf_kernels.py via ukf.PlanarUkf) against straightforward references: filterpy's
UnscentedKalmanFilter for the predict, the numpy `joseph_update_reference` for the updates. Random inputs with
a seed; the kernels promise the very same operations, so the comparison is exact (bit for bit), which is
tighter than the 1e-9 relative the evaluation needs (the filter amplifies rounding differences ~1e6 times)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from taco_mav.core import ukf_kernels
from taco_mav.core.preintegration import wrap_angle
from taco_mav.core.types import horizontal_sigma
from taco_mav.core.ukf import (PlanarUkf, _motion, _residual_x, fix_covariance, fix_covariance_reference, joseph_update,
                               joseph_update_reference, nearest_pd, process_noise)


class ReferenceUkf:
    """A reference PlanarUkf without the kernels: filterpy's predict, numpy Joseph updates."""

    def __init__(self, x0: np.ndarray, P0: np.ndarray, alpha: float = 1e-3, beta: float = 2.0,
                 kappa: float = 0.0) -> None:
        n = len(x0)
        points = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa, subtract=_residual_x)
        self.f = UnscentedKalmanFilter(dim_x=n, dim_z=2, dt=0.1, hx=lambda x: x[:2], fx=_motion, points=points,
                                       residual_x=_residual_x)
        self.f.x = np.asarray(x0, dtype=float).copy()
        self.f.P = nearest_pd(np.asarray(P0, dtype=float))
        self.h_theta = np.zeros((1, n))
        self.h_theta[0, 2] = 1.0
        if n >= 6:
            self.h_theta[0, 5] = 1.0

    def predict(self, d_fwd, d_left, d_theta, Q, dt=0.1, bias_decay=1.0):
        f = self.f
        f.Q = Q
        try:
            f.predict(dt=dt, d_fwd=d_fwd, d_left=d_left, d_theta=d_theta, bias_decay=bias_decay)
        except np.linalg.LinAlgError:
            f.P = nearest_pd(f.P, floor=1e-6)
            f.predict(dt=dt, d_fwd=d_fwd, d_left=d_left, d_theta=d_theta, bias_decay=bias_decay)
        f.x[2] = wrap_angle(f.x[2])
        f.P = nearest_pd(f.P)

    def _update(self, H, innovation, R):
        f = self.f
        f.x, f.P, nis = joseph_update_reference(f.x, f.P, H, innovation, R)
        f.x[2] = wrap_angle(f.x[2])
        return nis

    def update_position(self, z, R):
        H = np.zeros((2, len(self.f.x)))
        H[0, 0] = H[1, 1] = 1.0
        if len(self.f.x) == 8:  # a map fix reads position + the map's offset
            H[0, 6] = H[1, 7] = 1.0
        return self._update(H, np.asarray(z, dtype=float) - H @ self.f.x, R)

    def update_heading(self, theta, sigma):
        innovation = np.array([wrap_angle(theta - float(self.h_theta[0] @ self.f.x))])
        self._update(self.h_theta, innovation, np.array([[sigma * sigma]]))

    def update_speed_error(self, dv, sigma):
        H = np.zeros((1, len(self.f.x)))
        H[0, 3] = 1.0
        self._update(H, np.array([dv - self.f.x[3]]), np.array([[sigma * sigma]]))


def _random_cov(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T * scale + 1e-6 * np.eye(n)


@pytest.mark.parametrize("n", [3, 5, 6, 8])
def test_filter_matches_filterpy_and_numpy_reference_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(18 + n)
    for run in range(20):
        x0 = np.concatenate([rng.normal(0, 500, 2), [rng.uniform(-math.pi, math.pi)], rng.normal(0, 0.1, n - 3)])
        P0 = _random_cov(rng, n, 10.0 ** rng.uniform(-3, 2))
        fast, ref = PlanarUkf(x0, P0), ReferenceUkf(x0, P0)
        for step in range(60):
            Q = _random_cov(rng, n, 10.0 ** rng.uniform(-5, -1))
            inc = (rng.normal(1.0, 0.5), rng.normal(0, 0.05), rng.normal(0, 0.05 if step % 7 else 3.0))
            kw = dict(dt=float(rng.uniform(0.05, 0.15)), bias_decay=float(rng.uniform(0.99, 1.0)))
            fast.predict(*inc, Q, **kw)
            ref.predict(*inc, Q, **kw)
            theta = float(rng.uniform(-math.pi, math.pi))
            fast.update_heading(theta, 0.05)
            ref.update_heading(theta, 0.05)
            if n >= 5 and step % 5 == 0:
                dv = float(rng.normal(0, 1))
                fast.update_speed_error(dv, 0.02)
                ref.update_speed_error(dv, 0.02)
            if step % 4 == 0:
                z = ref.f.x[:2] + rng.normal(0, 3, 2)
                R = fix_covariance(float(rng.uniform(-3, 3)), float(rng.uniform(0.5, 8)), float(rng.uniform(1, 12)))
                assert fast.update_position(z, R) == ref.update_position(z, R)
            assert np.array_equal(fast.x, ref.f.x), (run, step)
            assert np.array_equal(fast.P, ref.f.P), (run, step)


@pytest.mark.parametrize("n", [3, 5, 6])
def test_joseph_update_matches_numpy_reference(n: int) -> None:
    """Arbitrary measurement rows (as the taco+ GNSS update builds them) and a rank-deficient case that needs the
    eigenvalue lift."""
    rng = np.random.default_rng(7 * n)
    for trial in range(300):
        m = int(rng.integers(1, min(n, 4) + 1))
        rows = rng.choice(n, size=m, replace=False)
        H = np.zeros((m, n))
        H[np.arange(m), rows] = 1.0
        x = rng.normal(0, 100, n)
        P = _random_cov(rng, n, 10.0 ** rng.uniform(-4, 3))
        if trial % 50 == 0:
            P[-1, :] = P[:, -1] = 0.0  # singular: the Joseph result needs nearest_pd's eigenvalue lift
        innov = rng.normal(0, 2, m)
        R = np.diag(rng.uniform(1e-4, 10, m))
        got, want = joseph_update(x, P, H, innov, R), joseph_update_reference(x, P, H, innov, R)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]) and got[2] == want[2]


def test_fix_covariance_kernel_matches_numpy() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        th, a, b = float(rng.uniform(-4, 4)), float(rng.uniform(0.1, 10)), float(rng.uniform(0.1, 10))
        assert np.array_equal(fix_covariance(th, a, b), fix_covariance_reference(th, a, b))


def test_process_noise_kernel_matches_numpy() -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        th, f, l, s = (float(v) for v in rng.uniform(0.01, 5, 4))
        dt, frame_dt = float(rng.uniform(0.001, 0.5)), 0.1
        scale = dt / frame_dt
        want = np.zeros((3, 3))
        want[:2, :2] = fix_covariance_reference(th, f, l) * scale
        want[2, 2] = s * s * scale
        assert np.array_equal(process_noise(th, f, l, s, dt, frame_dt), want)


def test_horizontal_sigma_kernel_matches_numpy() -> None:
    rng = np.random.default_rng(4)
    for _ in range(500):
        n = int(rng.choice([2, 3, 5, 6]))
        P = _random_cov(rng, n, 10.0 ** rng.uniform(-3, 4))
        want = float(np.sqrt(max(np.linalg.eigvalsh(P[:2, :2]).max(), 0.0)))
        assert horizontal_sigma(P) == want == ukf_kernels.horizontal_sigma(P)


def test_predict_recovers_from_an_indefinite_covariance_like_the_reference() -> None:
    """A P that is not positive definite makes the Cholesky fail: both lift it (floor 1e-6) and go on."""
    x0 = np.array([1.0, 2.0, 0.3])
    P0 = np.diag([1.0, 1.0, 1e-4])
    fast, ref = PlanarUkf(x0, P0), ReferenceUkf(x0, P0)
    bad = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1e-4]])  # eigenvalues 3, -1, 1e-4
    fast.set_state(x0, bad)
    ref.f.P = bad.copy()
    Q = np.diag([0.1, 0.1, 1e-4])
    fast.predict(1.0, 0.0, 0.01, Q)
    ref.predict(1.0, 0.0, 0.01, Q)
    assert np.array_equal(fast.x, ref.f.x) and np.array_equal(fast.P, ref.f.P)
    assert np.linalg.eigvalsh(fast.P).min() > 0


def test_positive_definiteness_decision_matches_eigvalsh_at_the_floor() -> None:
    """The kernels' PD test (a Cholesky with a wide margin, else LAPACK's eigvalsh) decides exactly as
    nearest_pd's eigvalsh(S).min() >= floor, also for eigenvalues within rounding of the floor."""
    rng = np.random.default_rng(6)
    floor = 1e-9
    for trial in range(3000):
        n = int(rng.choice([5, 6]))
        V, _ = np.linalg.qr(rng.normal(size=(n, n)))
        w = 10.0 ** rng.uniform(-8, 4, n)
        w[int(rng.integers(n))] = floor * (1.0 + float(rng.choice([-1e-3, -1e-9, 0.0, 1e-9, 1e-3, 1.0, 1e3])))
        S = (V * w) @ V.T
        S = 0.5 * (S + S.T)
        assert ukf_kernels.sym_pd(S, floor)[1] == bool(np.linalg.eigvalsh(S).min() >= floor), trial


def test_process_noise_plus_kernel_matches_numpy() -> None:
    """plus.noise.process_noise_plus (compiled) against its numpy formulation, with and without the compass bias."""
    from taco_mav.core.plus.noise import bias_decay, process_noise_plus
    from taco_mav.core.plus.params import PlusParams

    rng = np.random.default_rng(8)
    for sigma_beta in (0.0, 0.01):
        p = PlusParams(compass_bias_sigma_rad=sigma_beta)
        n = 6 if sigma_beta > 0 else 5
        for _ in range(200):
            theta, dt, dist = float(rng.uniform(-4, 4)), float(rng.uniform(1e-6, 0.5)), float(rng.uniform(0, 5))
            want = np.zeros((n, n))
            if n == 6:
                want[5, 5] = p.compass_bias_sigma_rad**2 * (1.0 - bias_decay(dt, p) ** 2)
            rw = p.q_pos_mps * p.q_pos_mps * dt
            want[:2, :2] = fix_covariance_reference(theta, p.q_fwd_per_m * dist, p.q_lat_per_m * dist) + rw * np.eye(2)
            want[2, 2] = p.q_theta_rad * p.q_theta_rad * dt
            want[3, 3] = p.q_speed_mps * p.q_speed_mps * dt
            want[4, 4] = p.q_bias_mps2 * p.q_bias_mps2 * dt
            assert np.array_equal(process_noise_plus(theta, dt, dist, p), want)


def test_read_only_install_without_a_cache_folder_still_imports_and_runs(tmp_path):
    """A read-only install in a service without a home folder (numba finds no cache folder): the kernels
    compile without a cache instead of failing at import, with one warning naming NUMBA_CACHE_DIR."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    import taco_mav

    if shutil.which("unshare") is None:
        pytest.skip("unshare not available")
    site, home = tmp_path / "site", tmp_path / "home"
    home.mkdir()
    shutil.copytree(Path(taco_mav.__file__).parent, site / "taco_mav",
                    ignore=shutil.ignore_patterns("__pycache__"))
    code = ("import logging; logging.basicConfig(); import numpy as np; import taco_mav.core.ukf_kernels as k; "
            "print('cache', k._JIT['cache']); print('wrap', k.wrap(4.0))")
    script = (f"mount --bind -o ro {tmp_path} {tmp_path} && cd / && "
              f"HOME={home} NUMBA_CACHE_DIR= PYTHONPATH={site} {sys.executable} -c \"{code}\"")
    proc = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, timeout=300)
    if "mount" in proc.stderr and proc.returncode != 0 and "cache" not in proc.stdout:
        pytest.skip(f"cannot make a read-only mount here: {proc.stderr.strip()[:200]}")
    assert proc.returncode == 0, proc.stderr
    assert "cache False" in proc.stdout
    assert abs(float(proc.stdout.split("wrap")[1]) - (4.0 - 2 * np.pi)) < 1e-12
    assert "NUMBA_CACHE_DIR" in proc.stderr


def test_sigma_point_weights_are_filterpys() -> None:
    """ukf.merwe_weights (the daemon does not import filterpy: it loads scipy.stats) against filterpy's
    MerweScaledSigmaPoints, to the bit, for every state size and a spread of alpha, beta, kappa."""
    from taco_mav.core.ukf import merwe_weights

    for n in (3, 5, 6, 8):
        for alpha, beta, kappa in ((1e-3, 2.0, 0.0), (0.5, 2.0, 1.0), (1.0, 0.0, 3.0 - n)):
            ref = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
            wm, wc = merwe_weights(n, alpha, beta, kappa)
            assert np.array_equal(wm, ref.Wm) and np.array_equal(wc, ref.Wc), (n, alpha, beta, kappa)
