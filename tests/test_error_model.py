import math

import pytest

from taco_mav.core.error_model import AnchorWindow, HighPass, MomentAccumulator, Moments, error_terms


def test_envelope_terms_hand_computed():
    res = Moments()
    for x in (1.0, -1.0, 1.0, -1.0):
        res = res.add(x)
    assert res.std == pytest.approx(1.0)
    w = AnchorWindow(4.0, 40.0, res)
    terms = error_terms(w, d_div=100.0, gyro_arw=1e-3)
    assert terms.cross == pytest.approx(3 * 40 * 1e-3 * 2.0)  # 3 d sigma_w sqrt(T) = 0.24 m
    assert terms.along == pytest.approx(0.5 * 1.0 * 16.0)  # 1/2 sigma_a T^2 = 8 m
    assert terms.divergence == pytest.approx(3.0)  # 0.03 d_div
    assert terms.epsilon == pytest.approx(8.0)


def test_cross_term_dominates_a_smooth_drive():
    terms = error_terms(AnchorWindow(9.0, 90.0, Moments()), d_div=0.0, gyro_arw=0.01)
    assert terms.along == 0.0
    assert terms.epsilon == pytest.approx(3 * 90 * 0.01 * 3.0)


def test_window_extends_with_merged_moments():
    xs = [0.3, -0.1, 0.7, 0.2, -0.5, 0.4]
    acc = MomentAccumulator()
    for x in xs[:3]:
        acc.add(x)
    first = acc.take()
    for x in xs[3:]:
        acc.add(x)
    w = AnchorWindow().extend(0.1, 1.0, first).extend(0.1, 1.5, acc.take())
    mean = sum(xs) / len(xs)
    std = math.sqrt(sum((x - mean) ** 2 for x in xs) / len(xs))
    assert w.elapsed == pytest.approx(0.2) and w.distance == pytest.approx(2.5)
    assert w.residual.std == pytest.approx(std)
    assert acc.n == 0  # take() clears


def test_highpass_removes_a_constant_and_keeps_a_step_edge():
    hp = HighPass(0.2)
    out = [hp.step(2.0, 0.01) for _ in range(3000)]
    assert abs(out[-1]) < 1e-9  # constant bias is absorbed
    y = hp.step(3.0, 0.01)
    assert y == pytest.approx(1.0 * hp.tau / (hp.tau + 0.01))  # a step passes almost whole
