"""The UKF kernels of `ukf_kernels` compiled ahead of time (numba.pycc) into an extension module that loads
without numba, so the live daemon loads nothing it never uses (its memory: docs/companion.md).

Why: the kernels loaded through numba's JIT cost the daemon about 130 MB of its peak resident set (numba's
typing registries and LLVM, libllvmlite's 70 MB of code pages, scipy.linalg), for about 1 MB of machine code.
Compiled ahead of time from the *same* functions (`ukf_kernels.<name>.py_func`, nothing is written twice) the
module needs neither numba nor LLVM at run time (it takes LAPACK and BLAS from scipy.linalg, as numba does).

The same numbers: the same numba front end and LLVM pipeline compile the same operations (no fastmath, no FMA
contraction), and the array arguments are typed with any layout ('A'), on which numba's np.dot and np.linalg
make the same BLAS and LAPACK calls. tests/test_ukf_aot.py checks every kernel against the JIT's results bit
for bit on random inputs (27 000 calls here: 0 differ, exceptions included); the golden runs did not change.
Calls cost a few microseconds more (predict 12 against 10 us), a few hundredths of a millisecond per second.

The module is built by `python -m taco_mav.core.ukf_aot` (about a minute of CPU and a C compiler; an install
step, as numba's first compile is) into the `__pycache__` folder beside `ukf_kernels.py`, named by a digest of
that file, these signatures, numba's and Python's versions: an edit of the kernels makes the old build
invisible, never stale. `load()` returns it, or None when it is not built (then `kernels` uses numba's JIT).
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import sys
import sysconfig
import tempfile
from pathlib import Path
from types import ModuleType

log = logging.getLogger(__name__)

_A1, _A2 = "f8[:]", "f8[:, :]"
# Every kernel `kernels` hands on, with the numba signature it is compiled for (arrays: float64, any layout;
# returns as the JIT's: C-ordered arrays).
SIGNATURES: dict[str, str] = {
    "wrap": "f8(f8)",
    "sym_pd": f"Tuple((f8[:, ::1], b1))({_A2}, f8)",
    "predict": f"Tuple((f8[::1], f8[:, ::1], b1))({_A1}, {_A2}, {_A2}, f8, {_A1}, {_A1}, f8, f8, f8, f8, f8, f8)",
    "joseph": f"Tuple((f8[:, ::1], f8[:, ::1], f8, b1))({_A2}, {_A2}, {_A1}, {_A2}, f8)",
    "scalar_update": f"Tuple((f8[::1], f8[:, ::1], b1))({_A1}, {_A2}, {_A2}, f8, f8, i8, f8)",
    "process_noise": "f8[:, ::1](f8, f8, f8, f8, f8)",
    "process_noise_plus": "f8[:, ::1](f8, f8, f8, i8, f8, f8, f8, f8, f8, f8, f8)",
    "horizontal_sigma": f"f8({_A2})",
    "fix_covariance": "f8[:, ::1](f8, f8, f8)",
}

_SOURCE = Path(__file__).with_name("ukf_kernels.py")


def module_name() -> str:
    """The extension's module name for the current kernels: a digest of ukf_kernels.py, SIGNATURES, numba's
    version (from its distribution's metadata: numba itself is not imported) and the Python version."""
    from importlib.metadata import version

    h = hashlib.sha256(_SOURCE.read_bytes())
    h.update(repr(sorted(SIGNATURES.items())).encode())
    h.update(f"numba {version('numba')} python {sys.version}".encode())
    return f"ukf_kernels_aot_{h.hexdigest()[:16]}"


def module_path() -> Path:
    """Where the extension for the current kernels is (or would be) built."""
    return _SOURCE.parent / "__pycache__" / (module_name() + sysconfig.get_config_var("EXT_SUFFIX"))


def load() -> ModuleType | None:
    """The ahead-of-time module for the current kernels, or None when it is not built (or does not load)."""
    path = module_path()
    if not path.is_file():
        return None
    try:
        spec = importlib.util.spec_from_file_location(module_name(), path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except (ImportError, OSError) as exc:
        log.warning("%s does not load (%s): the UKF kernels go through numba's JIT", path, exc)
        return None
    return module


def build() -> Path:
    """Compile the kernels ahead of time (numba.pycc; needs a C compiler) into `module_path()`, written whole
    or not at all; returns the path. Raises OSError when the folder is not writable."""
    import warnings

    from numba.core.errors import NumbaPerformanceWarning
    from numba.pycc import CC

    from taco_mav.core import ukf_kernels

    path = module_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        cc = CC(module_name())
        cc.output_dir = tmp
        cc.verbose = False
        for name, signature in SIGNATURES.items():
            cc.export(name, signature)(getattr(ukf_kernels, name).py_func)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NumbaPerformanceWarning)  # 'A' layouts: np.dot checks at run time
            cc.compile()
        os.replace(Path(tmp) / path.name, path)
    log.info("UKF kernels compiled ahead of time into %s", path)
    return path


def ensure_built() -> Path:
    """`module_path()`, built first when it is not there."""
    path = module_path()
    return path if path.is_file() else build()


if __name__ == "__main__":  # pragma: no cover - `python -m taco_mav.core.ukf_aot`: the install step
    logging.basicConfig(level=logging.INFO)
    log.info("UKF kernels ahead of time: %s", ensure_built())
