"""core/map_offset.py: the map's georeferencing offset learnt from fixes while the position is anchored."""

from __future__ import annotations

import numpy as np
import pytest

from taco_mav.core.map_offset import MapOffset, MapOffsetParams

TRUE_B = np.array([1.05, -0.40])  # m: a feature at world p appears in the map at p + b


def _fix_stream(mo: MapOffset, rng: np.random.Generator, n: int, p_sigma: float, r_sigma: float) -> None:
    """n fixes of a vehicle whose prior position is N(truth, p_sigma^2) and whose matcher errs by r_sigma,
    through the decoupled update (the state is not simulated: each fix starts from a fresh prior)."""
    P, R = p_sigma**2 * np.eye(2), r_sigma**2 * np.eye(2)
    for _ in range(n):
        p_err = rng.normal(0.0, p_sigma, 2)  # the prior's error
        fix_map = TRUE_B + rng.normal(0.0, r_sigma, 2)  # the matcher's answer relative to the truth, map frame
        innov = mo.correct(fix_map) - p_err
        mo.update(innov, P, R)


def test_disabled_changes_nothing() -> None:
    mo = MapOffset(MapOffsetParams())
    xy = np.array([[3.0, 4.0]])
    assert not mo.enabled and np.array_equal(mo.correct(xy), xy)
    mo.update(np.array([1.0, 1.0]), np.eye(2), np.eye(2))
    assert mo.fix_variance() == 0.0 and np.array_equal(mo.b, [0.0, 0.0]) and not mo.report_cov().any()


def test_learnt_while_anchored() -> None:
    """A precise anchor (5 cm, an RTK receiver or a surveyed start) and 0.4 m fixes: after 10 fixes b is within
    3 sigma of the truth, its sigma is below 0.2 m, and fixes are corrected by it."""
    mo = MapOffset(MapOffsetParams(georef_sigma_m=1.0))
    _fix_stream(mo, np.random.default_rng(3), 10, 0.05, 0.4)
    sigma = np.sqrt(np.diag(mo.cov))
    assert np.all(sigma < 0.2) and mo.updates == 10
    assert np.all(np.abs(mo.b - TRUE_B) < 3.0 * sigma), (mo.b, sigma)
    assert np.allclose(mo.correct(np.array([10.0, 20.0])), [10.0, 20.0] - mo.b)
    assert mo.report_cov() == pytest.approx(mo.cov)


def test_hardly_moves_when_loose() -> None:
    """Dead reckoning 5 m off: the same fixes teach b almost nothing (the state takes them instead), and b's
    variance stays near its prior."""
    mo = MapOffset(MapOffsetParams(georef_sigma_m=1.0))
    _fix_stream(mo, np.random.default_rng(3), 3, 5.0, 0.4)
    assert np.all(np.diag(mo.cov) > 0.85) and np.linalg.norm(mo.b) < 0.5


def test_consistent_over_seeds() -> None:
    """The reported sigma is honest: over 200 seeds the normalised error of b has a mean square near 2 (2 dof)."""
    nees = []
    for seed in range(200):
        mo = MapOffset(MapOffsetParams(georef_sigma_m=1.0))
        b = np.random.default_rng(1000 + seed).normal(0.0, 1.0, 2)  # the map's offset, from the prior
        rng = np.random.default_rng(seed)
        for _ in range(4):
            p_err, r = rng.normal(0.0, 0.3, 2), rng.normal(0.0, 0.5, 2)
            mo.update(mo.correct(b + r) - p_err, 0.09 * np.eye(2), 0.25 * np.eye(2))
        e = mo.b - b
        nees.append(float(e @ np.linalg.solve(mo.cov, e)))
    assert 1.6 < np.mean(nees) < 2.4, np.mean(nees)


def test_relocalisation_and_nonfinite_do_not_teach() -> None:
    mo = MapOffset(MapOffsetParams(georef_sigma_m=1.0))
    mo.update(np.array([30.0, 0.0]), 0.01 * np.eye(2), 0.25 * np.eye(2), learn=False)  # a relocalisation's jump
    mo.update(np.array([np.nan, 0.0]), 0.01 * np.eye(2), 0.25 * np.eye(2))
    assert np.array_equal(mo.b, [0.0, 0.0]) and mo.updates == 0 and mo.fixes_applied == 2
    assert mo.fix_variance() == pytest.approx(1.0)
    assert mo.report_cov() == pytest.approx(np.eye(2))  # a fix was fused: the state now carries the map's error
