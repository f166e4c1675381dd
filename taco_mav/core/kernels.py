"""The UKF kernels the estimator calls: `ukf_kernels` compiled ahead of time when that module is built
(`ukf_aot`: no numba, no LLVM in the process), else through numba's JIT (`ukf_kernels`, compiled or loaded from
numba's cache). The same functions and the same numbers either way (tests/test_ukf_aot.py); frames, units and
shapes as in ukf_kernels."""

from __future__ import annotations

import logging
from types import ModuleType

from taco_mav.core import ukf_aot

log = logging.getLogger(__name__)


def _impl() -> ModuleType:
    aot = ukf_aot.load()
    if aot is not None:
        return aot
    from taco_mav.core import ukf_kernels

    log.debug("UKF kernels through numba's JIT (build them ahead of time: python -m taco_mav.core.ukf_aot)")
    return ukf_kernels


_k = _impl()
AHEAD_OF_TIME: bool = _k.__name__ != "taco_mav.core.ukf_kernels"
wrap = _k.wrap
sym_pd = _k.sym_pd
predict = _k.predict
joseph = _k.joseph
scalar_update = _k.scalar_update
process_noise = _k.process_noise
process_noise_plus = _k.process_noise_plus
horizontal_sigma = _k.horizontal_sigma
fix_covariance = _k.fix_covariance


def warm_up() -> None:
    """Compile or load every kernel (`ukf_kernels.warm_up`); nothing to do for the ahead-of-time module."""
    if not AHEAD_OF_TIME:
        _k.warm_up()
