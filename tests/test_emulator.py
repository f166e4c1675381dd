"""FG2-statistics emulator: determinism, published error figures, failure modes, misses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from taco_mav.bench.emulator import sample
from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig, EmulatorConfig
from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.cvgl.emulator import EmulatorMatcher, Outcome, lognormal_params
from taco_mav.errors import ConfigError

CAMERA = GroundCamera.from_config(CameraConfig())
EMPTY = np.zeros((0, 0, 3), np.uint8)
TRUTH = (500_000.0, 5_400_000.0, 0.4)  # absolute UTM E, N and ENU heading


def psi_res(r: MatchResult) -> float:
    return math.atan2(r.R[1, 0], r.R[0, 0])


def five_crops(offset_m: float = 3.0) -> list[Crop]:
    centres = np.array(TRUTH[:2]) + np.array([[0, 0], [offset_m, 0], [-offset_m, 0], [0, offset_m], [0, -offset_m]])
    return [Crop(np.zeros((512, 512, 3), np.uint8), c, heading=0.35, m_per_px=0.2) for c in centres]


def frame(t: float) -> GroundFrame:
    return GroundFrame(EMPTY, t, CAMERA)


def test_deterministic_per_seed_and_independent_of_call_order() -> None:
    cfg = EmulatorConfig()
    a = EmulatorMatcher(cfg, lambda t: TRUTH, seed=7)
    b = EmulatorMatcher(cfg, lambda t: TRUTH, seed=7)
    first = a.match(frame(12.3), five_crops())
    b.match(frame(99.0), five_crops())  # an unrelated query in between changes nothing
    second = b.match(frame(12.3), five_crops())
    for x, y in zip(first, second):
        assert np.array_equal(x.t, y.t) and np.array_equal(x.R, y.R) and x.w == y.w
    other = EmulatorMatcher(cfg, lambda t: TRUTH, seed=8).match(frame(12.3), five_crops())
    assert not np.array_equal(first[0].t, other[0].t)
    # five crops draw five different errors
    assert len({float(r.t[0]) for r in first}) == 5


def test_result_contract_and_frame() -> None:
    """t is the true offset in the heading-up (forward, left) frame plus a sub-few-metre error."""
    cfg = dataclasses.replace(EmulatorConfig(), symmetric_lock_rate=0.0, silent_outlier_rate=0.0)
    m = EmulatorMatcher(cfg, lambda t: TRUTH, seed=0)
    crop = Crop(np.zeros((512, 512, 3), np.uint8), np.array(TRUTH[:2]) - [0.0, 10.0], heading=math.pi / 2,
                m_per_px=0.2)  # truth is 10 m north = 10 m forward when heading north
    errs = []
    for k in range(200):
        (r,) = m.match(frame(k * 0.1), [crop])
        assert np.allclose(r.R @ r.R.T, np.eye(2)) and 0.0 < r.w <= 1.0
        assert abs(psi_res(r) - (TRUTH[2] - math.pi / 2)) < 0.2
        errs.append(np.hypot(r.t[0] - 10.0, r.t[1]))
    assert np.median(errs) < 1.0


@pytest.mark.parametrize("cross", [False, True])
def test_median_and_mean_reproduce_config(cross: bool) -> None:
    cfg = dataclasses.replace(EmulatorConfig(), symmetric_lock_rate=0.0, silent_outlier_rate=0.0)
    err, outcomes = sample(cfg, 4000, cross, seed=3)
    median, mean = (4.15, 7.31) if cross else (0.51, 0.75)
    assert np.median(err) == pytest.approx(median, rel=0.08)
    assert np.mean(err) == pytest.approx(mean, rel=0.12)
    assert set(outcomes) == {Outcome.NOMINAL}


def test_lognormal_params() -> None:
    mu, sigma = lognormal_params(0.51, 0.75)
    assert math.exp(mu) == pytest.approx(0.51) and math.exp(mu + sigma**2 / 2) == pytest.approx(0.75)
    with pytest.raises(ConfigError):
        lognormal_params(1.0, 0.5)


def test_lock_and_outlier_rates_and_gate_visibility() -> None:
    cfg = dataclasses.replace(EmulatorConfig(), symmetric_lock_rate=0.1, silent_outlier_rate=0.05)
    m = EmulatorMatcher(cfg, lambda t: TRUTH, seed=1)
    crop = Crop(np.zeros((512, 512, 3), np.uint8), np.array(TRUTH[:2]), heading=TRUTH[2], m_per_px=0.2)
    kinds, psis, ws, errs = [], [], [], []
    for k in range(4000):
        (r,) = m.match(frame(k * 0.1), [crop])
        kinds.append(m.last_draws[0].outcome)
        psis.append(psi_res(r))
        ws.append(r.w)
        errs.append(np.hypot(*r.t))
    kinds_a, psis_a, ws_a, errs_a = np.array(kinds), np.abs(psis), np.array(ws), np.array(errs)
    lock, outl = kinds_a == Outcome.LOCK, kinds_a == Outcome.OUTLIER
    assert lock.mean() == pytest.approx(0.1, abs=0.015) and outl.mean() == pytest.approx(0.05, abs=0.01)
    assert (psis_a[lock] > 0.35).all() and ws_a[lock].min() >= 0.6  # caught by the gate, confident
    assert (psis_a[outl] < 0.35).all() and (errs_a[outl] >= 5.0).all() and (errs_a[outl] <= 20.0).all()


def test_outside_capture_radius_gives_low_weight_random_position() -> None:
    m = EmulatorMatcher(EmulatorConfig(), lambda t: TRUTH, seed=2)
    far = Crop(np.zeros((512, 512, 3), np.uint8), np.array(TRUTH[:2]) + [30.0, 0.0], heading=0.0, m_per_px=0.2)
    ws, ts = [], []
    for k in range(300):
        (r,) = m.match(frame(k * 0.1), [far])
        assert m.last_draws[0].outcome is Outcome.MISS
        ws.append(r.w)
        ts.append(r.t)
    ts_a = np.array(ts)
    assert max(ws) <= 0.15 and min(ws) > 0.0
    assert np.abs(ts_a).max() <= 51.2 and ts_a.std(axis=0).min() > 20.0  # spread over the 102 m crop


def test_weight_falls_with_error() -> None:
    cfg = dataclasses.replace(EmulatorConfig(), symmetric_lock_rate=0.0, silent_outlier_rate=0.0)
    m = EmulatorMatcher(cfg, lambda t: TRUTH, cross_area=True, seed=4)
    crop = Crop(np.zeros((512, 512, 3), np.uint8), np.array(TRUTH[:2]), heading=TRUTH[2], m_per_px=0.2)
    pairs = np.array([(np.hypot(*r.t), r.w) for k in range(1000) for r in m.match(frame(k * 0.1), [crop])])
    good, bad = pairs[pairs[:, 0] < 1.0, 1], pairs[pairs[:, 0] > 5.0, 1]
    assert len(good) > 50 and len(bad) > 50
    assert good.mean() > 0.6 and bad.mean() < 0.15


def test_registry_builds_emulator_and_refuses_without_truth() -> None:
    from taco_mav.config import Profile
    from taco_mav.cvgl.registry import make_matcher
    from taco_mav.errors import MatcherError

    profile = Profile(matcher="emulator")
    m = make_matcher(profile, lambda t: TRUTH, cross_area=True)
    assert isinstance(m, EmulatorMatcher) and m.cross_area and m.name == "emulator"
    with pytest.raises(MatcherError, match="needs ground truth"):
        make_matcher(profile)


def test_answers_with_the_cameras_true_position() -> None:
    """FG2 localises the camera: with a lever arm (1.08 m forward, 0.25 m right of the reference point) the
    emulator's answer is the camera's position plus the same noise draw as without one, i.e. every t moves by the
    lever arm rotated from the true heading into the crop's frame."""
    lever = (1.08, -0.25)
    plain = EmulatorMatcher(EmulatorConfig(), lambda t: TRUTH, seed=3)
    armed = EmulatorMatcher(EmulatorConfig(), lambda t: TRUTH, seed=3, lever_fwd_left=lever)
    rel = TRUTH[2] - 0.35  # true heading minus the crops' heading
    shift = np.array([math.cos(rel) * lever[0] - math.sin(rel) * lever[1],
                      math.sin(rel) * lever[0] + math.cos(rel) * lever[1]])
    for k in range(20):
        a, b = plain.match(frame(k * 0.1), five_crops()), armed.match(frame(k * 0.1), five_crops())
        for x, y in zip(a, b):
            assert y.t == pytest.approx(x.t + shift, abs=1e-9) and y.w == x.w and np.array_equal(y.R, x.R)


def test_place_field_is_a_standard_normal_field_with_the_configured_correlation_length() -> None:
    from taco_mav.cvgl.emulator import PlaceField
    length = 20.0
    p = np.array(TRUTH[:2])
    fields = [PlaceField(seed, length) for seed in range(3000)]
    assert PlaceField(5, length)(*p) == fields[5](*p)  # deterministic per seed
    z0 = np.array([f(*p) for f in fields])
    assert abs(z0.mean()) < 0.06 and z0.std() == pytest.approx(1.0, abs=0.05)
    for d in (0.5 * length, length, 2.0 * length):
        zd = np.array([f(p[0] + 0.6 * d, p[1] + 0.8 * d) for f in fields])
        assert np.corrcoef(z0, zd)[0, 1] == pytest.approx(math.exp(-0.5 * (d / length) ** 2), abs=0.06)


def _log_errors(cfg: EmulatorConfig, east: float, seeds: range) -> np.ndarray:
    """ln |error| of the five crops of one frame at (TRUTH + east metres), one row per seed (nominal answers); the
    frame time differs per place, so only the place's part can be shared between places."""
    truth = (TRUTH[0] + east, TRUTH[1], TRUTH[2])
    crops = [Crop(c.image, c.centre_utm + [east, 0.0], c.heading, c.m_per_px) for c in five_crops()]
    rows = []
    for seed in seeds:
        m = EmulatorMatcher(cfg, lambda t: truth, cross_area=True, seed=seed)
        m.match(frame(1.0 + east), crops)
        rows.append([math.log(d.err_m) for d in m.last_draws])
    return np.array(rows)


def test_a_place_share_correlates_nearby_answers_and_keeps_the_published_figures() -> None:
    nominal = dict(symmetric_lock_rate=0.0, silent_outlier_rate=0.0)
    iid = dataclasses.replace(EmulatorConfig(), **nominal)
    # share 0 (the default): the place field is never consulted; a length alone changes no draw
    a = _log_errors(iid, 0.0, range(3))
    assert np.array_equal(a, _log_errors(dataclasses.replace(iid, place_length_m=5.0), 0.0, range(3)))
    shared = dataclasses.replace(iid, place_share=0.8, place_length_m=20.0)
    here, near, far = (_log_errors(shared, e, range(1500)) for e in (0.0, 5.0, 200.0))
    crops_corr = np.corrcoef(here[:, 0], here[:, 1])[0, 1]
    assert crops_corr == pytest.approx(0.8, abs=0.06)  # crops of one frame share the place's part
    assert np.corrcoef(here[:, 0], near[:, 0])[0, 1] == pytest.approx(0.8 * math.exp(-0.5 * 0.25**2), abs=0.06)
    assert abs(np.corrcoef(here[:, 0], far[:, 0])[0, 1]) < 0.08
    assert abs(np.corrcoef(*_log_errors(iid, 0.0, range(1500))[:, :2].T)[0, 1]) < 0.08  # independent without
    err = np.exp(here.ravel())  # over many places (one field per seed) the published figures hold
    assert np.median(err) == pytest.approx(4.15, rel=0.08) and np.mean(err) == pytest.approx(7.31, rel=0.12)


def test_place_share_out_of_range_is_refused_by_name() -> None:
    from taco_mav.config.loading import profile_from_dict
    with pytest.raises(ConfigError, match="place_share"):
        profile_from_dict({"emulator": {"place_share": 1.5}})
