"""The UKF kernels compiled ahead of time (core/ukf_aot.py) against the same kernels through numba's JIT
(core/ukf_kernels.py): every kernel, random inputs with a seed (filter sizes 3, 5, 6 and 8; asymmetric and
not positive definite covariances too), the same results bit for bit, the same exceptions; and the module loads
without numba."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from taco_mav.core import ukf_aot, ukf_kernels


@pytest.fixture(scope="module")
def aot():
    """The ahead-of-time module, built first when it is not (about a minute: numba.pycc and a C compiler)."""
    ukf_aot.ensure_built()
    module = ukf_aot.load()
    assert module is not None
    return module


def _pd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    A = rng.normal(0.0, scale, (n, n))
    return A @ A.T + 1e-3 * np.eye(n)


def _calls(rng: np.random.Generator, trials: int):
    """(kernel name, arguments) of `trials` random filter steps."""
    for trial in range(trials):
        n = int(rng.choice([3, 5, 6, 8]))
        x = rng.normal(0.0, 3.0, n)
        P = _pd(rng, n, float(rng.choice([1e-4, 1e-2, 1.0, 10.0])))
        if trial % 7 == 0:
            P[0, 1] += 1e-3  # not symmetric
        if trial % 11 == 0:
            P = -P  # not positive definite: LinAlgError from the predict's Cholesky factor
        alpha = float(rng.choice([1e-3, 0.1, 1.0]))
        lam_n = alpha ** 2 * n
        Wm = np.full(2 * n + 1, 0.5 / lam_n)
        Wm[0] = (lam_n - n) / lam_n
        Wc = Wm.copy()
        Wc[0] += 3.0 - alpha ** 2
        d = rng.normal(0.0, 1.0, 3)
        yield "predict", (x, P, _pd(rng, n, 0.01), lam_n, Wm, Wc, 0.1, d[0], d[1], d[2], 0.99, 1e-9)
        m = int(rng.integers(1, min(n, 4) + 1))
        H = np.zeros((m, n))
        H[np.arange(m), rng.permutation(n)[:m]] = 1.0
        if trial % 3 == 0:
            H = rng.normal(0.0, 1.0, (m, n))
        yield "joseph", (P, H, rng.normal(0.0, 1.0, m), _pd(rng, m, 0.5), 1e-9)
        yield "scalar_update", (x, P, np.eye(n)[2:3].copy(), 0.3, 0.5, int(rng.integers(-1, n)), 1e-9)
        yield "horizontal_sigma", (P,)
        th = float(rng.normal())
        yield "fix_covariance", (th, 1.3, 0.4)
        yield "process_noise", (th, 1.3, 0.4, 0.1, 0.7)
        yield "process_noise_plus", (th, 0.1, 2.0, max(n, 5), 1e-4, 0.1, 0.01, 0.01, 0.002, 0.2, 0.005)
        yield "sym_pd", (P, 1e-9)
        yield "wrap", (5.0 * th,)


def _run(module, name: str, args: tuple):
    try:
        return getattr(module, name)(*args)
    except Exception as exc:  # noqa: BLE001 - the exception is part of what must agree
        return type(exc)


def _same(a, b) -> bool:
    if isinstance(a, tuple):
        return isinstance(b, tuple) and len(a) == len(b) and all(_same(u, v) for u, v in zip(a, b))
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape
                and a.flags.c_contiguous == b.flags.c_contiguous and np.array_equal(a, b))
    return type(a) is type(b) and a == b


def test_every_kernel_gives_the_jit_numbers_bit_for_bit(aot) -> None:
    assert set(ukf_aot.SIGNATURES) == {"wrap", "sym_pd", "predict", "joseph", "scalar_update", "process_noise",
                                       "process_noise_plus", "horizontal_sigma", "fix_covariance"}
    counts = {"calls": 0, "differ": 0, "raised": 0}
    for name, args in _calls(np.random.default_rng(0), 400):
        want, got = _run(ukf_kernels, name, args), _run(aot, name, args)
        counts["calls"] += 1
        counts["differ"] += not _same(want, got)
        counts["raised"] += isinstance(want, type)
    assert counts["calls"] == 3600 and counts["raised"] >= 30  # the -P cases: LinAlgError, in both
    assert counts["differ"] == 0


def test_the_module_loads_without_numba(aot) -> None:
    code = ("import sys; from taco_mav.core import kernels, ukf; f = ukf.PlanarUkf.__name__; "
            "print(kernels.AHEAD_OF_TIME, 'numba' in sys.modules, 'llvmlite' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "False", "False"]


def test_the_module_is_named_by_the_kernels_it_was_built_from() -> None:
    name = ukf_aot.module_name()
    assert name.startswith("ukf_kernels_aot_") and len(name) == len("ukf_kernels_aot_") + 16
    assert ukf_aot.module_path().parent == ukf_aot._SOURCE.parent / "__pycache__"
    assert ukf_aot.module_path().name.startswith(name)
