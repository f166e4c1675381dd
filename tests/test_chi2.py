"""chi2_isf_even: scipy's chi-square quantiles for even degrees of freedom, without scipy in the daemon."""

from __future__ import annotations

import pytest
from scipy.stats import chi2

from taco_mav.core.chi2 import chi2_isf_even


@pytest.mark.parametrize("dof", [2, 4, 6, 10, 14, 20, 50, 100, 200, 398, 1000])
@pytest.mark.parametrize("tail", [1e-9, 1e-6, 1e-4, 1e-3, 0.01, 0.05, 0.3, 0.5, 0.9, 0.999])
def test_it_is_scipys_quantile(dof: int, tail: float) -> None:
    want = float(chi2.isf(tail, dof))
    assert chi2_isf_even(dof, tail) == pytest.approx(want, rel=1e-10)


def test_two_degrees_have_the_closed_form() -> None:
    """chi2(2) is an exponential of mean 2: x = -2 ln(tail)."""
    import math

    for tail in (1e-4, 0.1, 0.5):
        assert chi2_isf_even(2, tail) == pytest.approx(-2.0 * math.log(tail), rel=1e-14)


@pytest.mark.parametrize("dof, tail", [(3, 0.1), (0, 0.1), (4, 0.0), (4, 1.0), (4, -0.5)])
def test_odd_or_out_of_range_arguments_are_refused(dof: int, tail: float) -> None:
    with pytest.raises(ValueError, match="dof must be even"):
        chi2_isf_even(dof, tail)
