"""taco+ building blocks: process noise, search patterns, consensus, the lock state machine, stationary
detection, the 5- and 6-state filter, the adaptive fix-noise scale."""

import math

import numpy as np
import pytest

from taco_mav.core.plus.lock import LockMonitor, LockState
from taco_mav.core.plus.noise import (
    FixNoiseScale,
    VarianceFactor,
    bias_decay,
    process_noise_plus,
)
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.search import (
    consensus,
    cross_arm,
    defer_answer,
    grid_rings,
    hex_offsets,
)
from taco_mav.core.plus.stationary import StationaryDetector
from taco_mav.core.ukf import PlanarUkf


def test_process_noise_grows_with_time_and_distance_in_the_body_frame():
    p = PlusParams(q_pos_mps=0.0, q_fwd_per_m=0.01, q_lat_per_m=0.02)
    Q = process_noise_plus(math.pi / 2, 0.1, 10.0, p)  # heading north: forward = +y
    assert Q.shape == (6, 6)
    assert Q[1, 1] == pytest.approx(0.01)  # (0.01 * 10)^2 along track
    assert Q[0, 0] == pytest.approx(0.04)  # (0.02 * 10)^2 cross track
    assert Q[3, 3] == pytest.approx(p.q_speed_mps**2 * 0.1)
    # compass bias: Gauss-Markov driving noise keeps its stationary variance sigma^2
    d = bias_decay(0.1, p)
    assert d == pytest.approx(math.exp(-0.1 / p.compass_bias_tau_s))
    assert d * d * p.compass_bias_sigma_rad**2 + Q[5, 5] == pytest.approx(p.compass_bias_sigma_rad**2)
    assert np.all(np.linalg.eigvalsh(Q) >= -1e-15)
    assert process_noise_plus(0.0, 0.1, 1.0, PlusParams(compass_bias_sigma_rad=0.0)).shape == (5, 5)


def test_fix_noise_scale_learns_the_matchers_real_sigma():
    rng = np.random.default_rng(4)
    R0 = np.diag([1.5**2, 3.0**2])  # the paper's mapping at w = 1
    P = np.diag([0.2**2, 0.3**2])  # prior position covariance at each fix
    est = FixNoiseScale(lo=0.05, hi=2.0, window=10)
    scales = []
    for _ in range(400):  # true fix noise = 0.4 x R0's sigmas, true prior error ~ N(0, P)
        innov = rng.multivariate_normal(np.zeros(2), P + 0.16 * R0)
        scales.append(est.update(innov, P, R0))
    assert np.median(scales[100:]) == pytest.approx(0.4, abs=0.06)
    # clipped to [lo, hi]: a perfect matcher stops at lo, a matcher much worse than R0 at hi
    lo = FixNoiseScale(lo=0.3, hi=2.0, window=10)
    hi = FixNoiseScale(lo=0.3, hi=2.0, window=10)
    for _ in range(50):
        lo.update(np.zeros(2), P, R0)
        hi.update(np.array([40.0, 40.0]), P, R0)
    assert lo.scale == pytest.approx(0.3, abs=0.01)
    assert hi.scale == pytest.approx(2.0)


@pytest.mark.parametrize("rings", [1, 2, 3, 4])
def test_hex_grid_covers_its_disc(rings: int):
    spacing = 15.0
    pts = hex_offsets(rings, spacing)
    assert len(pts) == 1 + 3 * rings * (rings + 1)
    assert len(np.unique(np.round(pts, 6), axis=0)) == len(pts)
    rng = np.random.default_rng(0)
    r = rings * spacing * np.sqrt(rng.uniform(0, 1, 2000)) * 0.999
    a = rng.uniform(0, 2 * np.pi, 2000)
    probe = np.column_stack([r * np.cos(a), r * np.sin(a)])
    nearest = np.min(np.linalg.norm(probe[:, None] - pts[None], axis=-1), axis=1)
    # inside the outer ring's hexagon every point is within spacing / sqrt(3); near its corners, spacing
    assert np.percentile(nearest, 90) <= spacing / math.sqrt(3) + 1e-6
    assert nearest.max() <= spacing + 1e-6


def test_search_sizes_follow_the_uncertainty():
    p = PlusParams()
    assert cross_arm(0.1, p) == p.cross_min_m
    assert cross_arm(100.0, p) == p.cross_max_m
    assert grid_rings(1.0, p) == 1
    assert grid_rings(20.0, p) == 4
    assert grid_rings(1000.0, p) == p.grid_max_rings


def test_consensus_prefers_the_agreeing_cluster_over_the_single_heaviest():
    xy = np.array([[0.0, 0.0], [0.5, 0.2], [0.3, -0.4], [25.0, 3.0], [9.0, 9.0]])
    w = np.array([0.6, 0.6, 0.5, 0.9, 0.7])
    usable = np.array([True, True, True, True, False])
    c = consensus(xy, w, usable, 3.0)
    assert c is not None and c.index == 0 and c.support == 3
    assert np.allclose(c.xy, (w[:3, None] * xy[:3]).sum(0) / w[:3].sum())
    assert consensus(xy, w, np.zeros(5, bool), 3.0) is None
    # power 2 is the inverse-variance mean under sigma ~ 1/w (weights w^2), same cluster and weight
    c2 = consensus(xy, w, usable, 3.0, power=2.0)
    assert c2.index == c.index and c2.support == c.support and c2.weight == c.weight
    assert np.allclose(c2.xy, (w[:3, None] ** 2 * xy[:3]).sum(0) / (w[:3] ** 2).sum())


def test_lock_monitor_needs_misses_and_time_then_confirmations():
    m = LockMonitor(lost_after=3, lost_after_s=5.0, capture_radius_m=20.0, confirm_fixes=2)
    for t in (1.0, 2.0, 3.0, 5.5):
        assert not m.on_failure(t, "weak")  # enough misses, but the run has lasted only 4.5 s
    assert m.on_failure(6.5, "weak") and m.state is LockState.LOST and m.losses == 1
    m.on_failure(7.0, "weak")
    assert m.attempts == 1
    m.on_relocalised(7.5, 35.0)
    assert m.state is LockState.CONFIRMING
    m.on_accepted(8.0)
    assert m.state is LockState.CONFIRMING
    m.on_accepted(8.5)
    assert m.state is LockState.LOCKED and m.recoveries == 1
    assert [k for _, k, _ in m.events] == ["lock_lost", "relocalised", "recovered"]
    # a burst of failures long after the last accepted fix is still only a burst
    for t in (100.0, 100.5, 101.0, 101.5, 102.0):
        assert not m.on_failure(t, "innovation_gate")
    m.on_accepted(103.0)
    assert m.misses == 0 and m.state is LockState.LOCKED
    assert m.on_uncertainty(109.0, 7.0) and m.state is LockState.LOST  # 3 sigma = 21 m > capture radius


def test_stationary_detector():
    det = StationaryDetector(1.0, 0.02, 0.05)
    rng = np.random.default_rng(0)
    for k in range(100):
        det.add(k * 0.01, tuple(np.array([0.0, 0.0, -9.81]) + rng.normal(0, 0.01, 3)), (0.0, 0.0, 0.001))
    assert det.stationary
    det.add(1.0, (0.0, 0.0, -9.81), (0.0, 0.0, 0.1))  # turning
    assert not det.stationary
    shaky = StationaryDetector(1.0, 0.02, 0.05)
    for k in range(100):
        shaky.add(k * 0.01, (rng.normal(0, 0.3), 0.0, -9.81), (0.0, 0.0, 0.0))
    assert not shaky.stationary


def test_five_state_motion_uses_speed_error_and_bias():
    P0 = np.diag([1e-4, 1e-4, 1e-6, 1.0, 1e-8])
    f = PlanarUkf(np.array([0.0, 0.0, 0.0, 0.5, 0.1]), P0)
    Q = np.diag([1e-9] * 5)
    f.predict(1.0, 0.0, 0.0, Q, dt=0.1)
    assert f.P[0, 3] > 0.05  # position and speed error are correlated after one step
    # forward = 1.0 + 0.5 * 0.1 - 0.5 * 0.1 * 0.01 ; dv = 0.5 - 0.1 * 0.1
    assert f.x[0] == pytest.approx(1.0 + 0.05 - 0.0005, abs=1e-6)
    assert f.x[3] == pytest.approx(0.49, abs=1e-9)
    f.update_speed_error(0.0, 0.01)
    assert abs(f.x[3]) < 0.01
    with pytest.raises(ValueError):
        PlanarUkf(np.zeros(4), np.eye(4))
    with pytest.raises(ValueError):
        PlanarUkf(np.zeros(3), np.eye(3)).update_speed_error(0.0, 0.1)


def test_six_state_filter_separates_a_compass_bias_from_the_heading():
    """Drive straight east for 60 s with a compass that reads 0.02 rad too high; position fixes every 5 s make
    the bias observable, so theta converges to the truth and beta to the bias (the compass alone cannot)."""
    bias, sigma_b = 0.02, 0.03
    P0 = np.diag([0.01, 0.01, 0.05**2, 1e-4, 1e-6, sigma_b**2])
    f = PlanarUkf(np.array([0.0, 0.0, bias, 0.0, 0.0, 0.0]), P0)
    Q = np.diag([1e-6, 1e-6, 1e-8, 1e-8, 1e-10, 1e-10])
    x = 0.0
    for k in range(1, 601):
        # the preintegrator rotated by the biased compass: a 1 m step "east" at heading `bias`
        f.predict(1.0, 0.0, 0.0, Q, dt=0.1, bias_decay=1.0)
        f.update_heading(bias, 0.01)
        x += 1.0
        if k % 50 == 0:
            f.update_position(np.array([x, 0.0]), np.diag([0.2**2, 0.2**2]))
    assert f.x[2] == pytest.approx(0.0, abs=0.003)  # heading: the truth, not the compass
    assert f.x[5] == pytest.approx(bias, abs=0.003)
    assert abs(f.x[1]) < 0.3  # the track is no longer bent by the bias (60 m x 0.02 rad = 1.2 m without)


def test_variance_factor_is_half_the_mean_nis_of_the_fixes():
    """2-D innovations drawn from k (P + R) give a mean NIS of 2 k against P + R, so the factor that
    makes the reported covariance honest is k; it starts at 1 and is clipped to [lo, hi]."""
    rng = np.random.default_rng(5)
    S = np.diag([1.0, 4.0])  # P + R the filter believes, m^2
    for k in (0.1, 0.5, 2.0):
        vf = VarianceFactor(lo=0.01, hi=4.0, window=20)
        assert vf.factor == 1.0
        ks = []
        for _ in range(400):
            nu = rng.multivariate_normal(np.zeros(2), k * S)
            ks.append(vf.update(float(nu @ np.linalg.solve(S, nu))))
        assert np.median(ks[100:]) == pytest.approx(k, rel=0.2)
    vf = VarianceFactor(lo=0.1, hi=4.0, window=20)
    for _ in range(100):
        vf.update(0.0)
    assert vf.factor == pytest.approx(0.1)
    for _ in range(100):
        vf.update(1e6)  # one sample is capped (50), the factor at hi
    assert vf.factor == pytest.approx(4.0)


def test_variance_factor_ignores_a_non_finite_nis_and_resets_to_the_prior():
    """A NaN NIS (from a non-finite P) must not poison the factor for good; a relocalisation forgets it."""
    vf = VarianceFactor(lo=0.1, hi=4.0, window=20)
    for _ in range(30):
        vf.update(0.0)  # NIS 0 where 2 is honest: k falls to the clip
    assert vf.factor == pytest.approx(0.1)
    assert vf.update(float("nan")) == pytest.approx(vf.factor) and np.isfinite(vf.factor)
    assert vf.update(float("inf")) == pytest.approx(vf.factor) and vf.n == 30
    vf.reset()
    assert vf.factor == 1.0 and vf.n == 0


def test_defer_answer_only_a_weak_answer_while_healthy_and_within_its_limits():
    """A weak answer is deferred only below defer_w, while healthy (locked, guard quiet, prior 1-sigma
    below trigger_sigma_m), fewer than defer_max times in a row and within trigger_distance_m + defer_span_m."""
    p = PlusParams(defer_w=0.6, defer_max=2, trigger_sigma_m=3.0, trigger_distance_m=40.0, defer_span_m=20.0)
    ok = dict(deferred=0, healthy=True, sigma_h=1.0, since_fix_m=45.0, p=p)
    assert defer_answer(0.4, **ok)
    assert not defer_answer(0.6, **ok)  # strong enough
    assert not defer_answer(0.4, **{**ok, "deferred": 2})  # defer_max reached: take it
    assert not defer_answer(0.4, **{**ok, "healthy": False})
    assert not defer_answer(0.4, **{**ok, "sigma_h": 3.0})  # the covariance trigger's uncertainty
    assert not defer_answer(0.4, **{**ok, "since_fix_m": 60.0})  # 40 + 20 m driven since the last fix
    assert defer_answer(0.4, **{**ok, "since_fix_m": 600.0, "p": PlusParams(defer_w=0.6, defer_span_m=0.0)})
    assert not defer_answer(0.1, **{**ok, "p": PlusParams()})  # off by default
