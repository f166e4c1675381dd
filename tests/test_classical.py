"""The classical matcher recovers known offsets and rotations on rendered frames of a textured GeoTIFF."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rasterio.transform import from_origin

from taco_mav.bench.classical import confidence_figures, confidence_samples, textured_mosaic, write_geotiff
from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import CameraConfig, ClassicalMatcherConfig
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.classical import PSR_AT_HALF_WEIGHT, PSR_LOGISTIC_SCALE, W_CALIBRATION, ClassicalMatcher, psr_weight
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.datasets.synthetic.gap import MapGap, alter_mosaic, occlude_frame
from taco_mav.datasets.synthetic.render import GroundRenderer
from taco_mav.errors import MatcherError

WEST, NORTH, RES, SIZE = 500_000.0, 5_430_000.0, 0.2, 1500


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> tuple[GroundRenderer, SatelliteMap, ClassicalMatcher]:
    mosaic = textured_mosaic(7, SIZE, RES)
    tif = Path(tmp_path_factory.mktemp("classical")) / "mosaic.tif"
    write_geotiff(tif, mosaic, WEST, NORTH, RES)
    cam = GroundCamera.from_config(CameraConfig())
    renderer = GroundRenderer(mosaic, from_origin(WEST, NORTH, RES, RES), cam, max_range_m=80.0)
    smap = SatelliteMap(tif)
    yield renderer, smap, ClassicalMatcher(ClassicalMatcherConfig(), cam)
    smap.close()


def _psi(res) -> float:
    """Residual yaw psi_res = atan2(R10, R00), radians CCW."""
    return math.atan2(res.R[1, 0], res.R[0, 0])


def _crop_at(smap: SatelliteMap, true_en: np.ndarray, heading: float, fwd: float, left: float):
    """Crop centred so that the vehicle sits at (fwd, left) metres from the centre in the crop frame."""
    c, s = math.cos(heading), math.sin(heading)
    centre = true_en - fwd * np.array([c, s]) - left * np.array([-s, c])
    return smap.crop(centre, heading, 512, 0.2)


@pytest.mark.parametrize("psi_deg", [5.0, -5.0])
def test_recovers_known_offset_and_rotation(world, psi_deg: float) -> None:
    renderer, smap, matcher = world
    true_en = np.array([WEST + 150.0, NORTH - 140.0])
    theta = math.radians(63.0)
    frame = GroundFrame(renderer.render((true_en[0], true_en[1], theta)), 0.0, renderer.camera)
    # The query heading is off by -psi: the true heading is query + psi, so the matcher must report +psi.
    q_heading = theta - math.radians(psi_deg)
    crop = _crop_at(smap, true_en, q_heading, 6.0, -4.0)
    (res,) = matcher.match(frame, [crop])
    assert np.hypot(*(res.t - [6.0, -4.0])) < 0.5, res.t
    assert abs(math.degrees(_psi(res)) - psi_deg) < 1.5, math.degrees(_psi(res))
    np.testing.assert_allclose(res.R @ res.R.T, np.eye(2), atol=1e-12)
    assert 0.0 < res.w <= 1.0 and res.elapsed_s > 0.0


def test_five_crops_in_order_and_true_area_outweighs_unrelated(world) -> None:
    renderer, smap, matcher = world
    true_en = np.array([WEST + 170.0, NORTH - 120.0])
    theta = math.radians(-100.0)
    frame = GroundFrame(renderer.render((true_en[0], true_en[1], theta)), 0.0, renderer.camera)
    offsets = [(0.0, 0.0), (8.0, 0.0), (-8.0, 0.0), (0.0, 8.0), (0.0, -8.0)]
    crops = [_crop_at(smap, true_en, theta, f, l) for f, l in offsets]
    unrelated = smap.crop(true_en + np.array([-110.0, -120.0]), theta, 512, 0.2)
    res = matcher.match(frame, crops + [unrelated])
    assert len(res) == 6
    for r, off in zip(res[:5], offsets):
        assert np.hypot(*(r.t - off)) < 0.5, (r.t, off)
        assert abs(_psi(r)) < math.radians(1.5)
    assert min(r.w for r in res[:5]) > res[5].w + 0.1, [r.w for r in res]


def test_partially_off_map_crop_still_matches(world) -> None:
    renderer, smap, matcher = world
    # Vehicle 30 m from the western edge looking north: the crop's left side is off the mosaic (zeros).
    true_en = np.array([WEST + 30.0, NORTH - 150.0])
    theta = math.radians(90.0)
    frame = GroundFrame(renderer.render((true_en[0], true_en[1], theta)), 0.0, renderer.camera)
    c, s = math.cos(theta), math.sin(theta)
    crop = smap.crop(true_en - 3.0 * np.array([c, s]), theta, 512, 0.2, min_valid=0.5)
    assert crop.valid_fraction < 0.95
    (res,) = matcher.match(frame, [crop])
    assert np.hypot(*(res.t - [3.0, 0.0])) < 0.5, res.t


def test_empty_crop_list_gives_empty_answer(world) -> None:
    renderer, _, matcher = world
    frame = GroundFrame(renderer.render((WEST + 150.0, NORTH - 150.0, 0.0)), 0.0, renderer.camera)
    assert matcher.match(frame, []) == []


def test_crops_of_two_sizes_in_one_trigger_are_refused_by_name(world) -> None:
    """One FFT size serves a trigger (its templates are cached at it): crops that resample to two sizes are an
    error naming both, not a shape error from inside OpenCV."""
    renderer, smap, matcher = world
    true_en = np.array([WEST + 150.0, NORTH - 150.0])
    frame = GroundFrame(renderer.render((true_en[0], true_en[1], 0.0)), 0.0, renderer.camera)
    crops = [smap.crop(true_en, 0.0, 512, 0.2), smap.crop(true_en, 0.0, 384, 0.2)]
    with pytest.raises(MatcherError, match=r"share one size .* got \[128, 171\] px"):
        matcher.match(frame, crops)


def test_psr_weight_is_a_logistic_around_the_profile_midpoint() -> None:
    mid = PSR_AT_HALF_WEIGHT
    assert psr_weight(mid) == pytest.approx(0.5)
    assert psr_weight(mid + PSR_LOGISTIC_SCALE) == pytest.approx(1.0 / (1.0 + math.exp(-1.0)))
    ws = [psr_weight(p) for p in np.linspace(0.0, 30.0, 61)]
    assert all(b >= a for a, b in zip(ws, ws[1:]))  # monotone
    assert 0.0 < ws[0] < 1e-3 and ws[-1] == pytest.approx(1.0)
    assert psr_weight(-1e9) > 0.0  # w stays in (0, 1], no overflow


def test_chance_peaks_get_low_weight_and_correct_matches_high() -> None:
    """Crops of a different place (chance peaks) get w < 0.1 on median, correct matches (error < 3 m, crop
    offsets 0-30 m) w > 0.5 on median; w ranks correct above wrong matches (seed 6: not used to calibrate w)."""
    samples = confidence_samples(seed=6, trials=40, chance_trials=30)
    ok = (samples["error_m"] < 3.0) & ~samples["chance"]
    assert ok.sum() >= 20
    assert np.median(samples["w"][samples["chance"]]) < 0.1
    assert np.median(samples["w"][ok]) > 0.5
    figures = confidence_figures(samples)
    assert figures["classical_w_auc"] > 0.95
    assert figures["classical_w_median_chance"] == pytest.approx(np.median(samples["w"][samples["chance"]]))
    # PSR and w agree: w is the logistic of the recorded PSR, with the default descriptor's calibration
    mid, scale = W_CALIBRATION[ClassicalMatcherConfig().descriptor]
    np.testing.assert_allclose(samples["w"], [psr_weight(p, mid, scale) for p in samples["psr"]])


# ---------------------------------------------------------------- appearance gap
GAP_POSES = 12


@pytest.fixture(scope="module")
def gap_map(world, tmp_path_factory: pytest.TempPathFactory) -> SatelliteMap:
    """The fixture's mosaic re-photographed: gain, gamma, autumn tint, moved shadows, 0.4 m/px, and a change of
    the materials' brightness order (`MapGap(fold=0.45)`); camera frames stay rendered from the original."""
    mosaic = textured_mosaic(7, SIZE, RES)
    tif = Path(tmp_path_factory.mktemp("gap")) / "gap.tif"
    write_geotiff(tif, alter_mosaic(mosaic, RES, seed=3, gap=MapGap(fold=0.45)), WEST, NORTH, RES)
    smap = SatelliteMap(tif)
    yield smap
    smap.close()


def _gap_errors(renderer, smap, matcher: ClassicalMatcher, occlude: bool = False) -> np.ndarray:
    """Fix errors (m) of single-crop matches at GAP_POSES seeded poses, the vehicle 0-10 m from the crop
    centre, the query heading within +-3 deg of the truth."""
    rng = np.random.default_rng(5)
    errors = []
    for k in range(GAP_POSES):
        true_en = np.array([WEST + rng.uniform(130, 170), NORTH - rng.uniform(130, 170)])
        theta = rng.uniform(-math.pi, math.pi)
        image = renderer.render((true_en[0], true_en[1], theta))
        if occlude:
            image = occlude_frame(image, renderer.camera, seed=100 + k)[0]
        q = theta - math.radians(rng.uniform(-3, 3))
        r, a = rng.uniform(0, 10), rng.uniform(-math.pi, math.pi)
        fwd, left = r * math.cos(a), r * math.sin(a)
        (res,) = matcher.match(GroundFrame(image, 0.0, renderer.camera), [_crop_at(smap, true_en, q, fwd, left)])
        errors.append(float(np.hypot(*(res.t - [fwd, left]))))
    return np.array(errors)


def test_orientation_descriptor_survives_a_brightness_order_change_that_defeats_lcn(world, gap_map) -> None:
    """Same frames, same crops of the re-photographed map: grey-level LCN correlates anti-correlated pixels and
    fails; gradient orientation, blind to an edge's polarity, keeps sub-metre fixes on most of them (measured:
    lcn median 17.6 m, none of 12 within 2 m; orientation median 0.52 m, 10 of 12 within 2 m)."""
    renderer, _, _ = world
    old = ClassicalMatcher(ClassicalMatcherConfig(descriptor="lcn", mask_vertical=False), renderer.camera)
    new = ClassicalMatcher(ClassicalMatcherConfig(descriptor="orientation"), renderer.camera)
    e_old = _gap_errors(renderer, gap_map, old)
    e_new = _gap_errors(renderer, gap_map, new)
    assert np.median(e_old) > 5.0 and np.mean(e_old < 2.0) <= 1 / 3, np.round(e_old, 1)
    assert np.median(e_new) < 1.0 and np.mean(e_new < 2.0) >= 3 / 4, np.round(e_new, 1)


def test_orientation_with_masks_survives_the_gap_and_vertical_occluders(world, gap_map) -> None:
    """The same gap plus three upright boxes (poles, cars, facades) in every camera frame (measured: median
    0.43 m, 9 of 12 within 2 m)."""
    renderer, _, _ = world
    new = ClassicalMatcher(ClassicalMatcherConfig(), renderer.camera)
    e = _gap_errors(renderer, gap_map, new, occlude=True)
    assert np.median(e) < 1.0 and np.mean(e < 2.0) >= 2 / 3, np.round(e, 1)


def test_the_correlation_is_the_circular_cross_correlation_over_the_searched_shifts(world) -> None:
    """`_corr` on OpenCV's packed spectra (`_spectra`) is sum_c sum_x f_c(x + s) t_c(x) over the searched shifts s,
    as numpy's float64 FFT computes it, to float32 rounding: a crop correlated with a template, several channels and
    one (the direction of the shift and the channel sum are what a packed layout could get wrong)."""
    from taco_mav.cvgl.classical import _spectra

    _, _, matcher = world
    matcher._setup_fft(171)
    ny, nx = matcher._fft_shape
    rng = np.random.default_rng(5)
    f = np.zeros((3, ny, nx), np.float32)
    f[:, :171, :171] = rng.standard_normal((3, 171, 171))
    t = np.zeros((3, ny, nx), np.float32)
    h, w = matcher._mask.shape
    t[:, :h, :w] = rng.standard_normal((3, h, w)) * matcher._mask
    want = np.fft.irfft2((np.fft.rfft2(f.astype(np.float64)) * np.conj(np.fft.rfft2(t.astype(np.float64)))).sum(0),
                         s=(ny, nx))[np.ix_(matcher._iy, matcher._ix)]
    got = matcher._corr(_spectra(f), _spectra(t))
    scale = float(np.abs(want).max())
    assert got.shape == want.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-5 * scale)
    one = matcher._corr(_spectra(f[0]), _spectra(t[0]))
    want1 = np.fft.irfft2(np.fft.rfft2(f[0].astype(np.float64)) * np.conj(np.fft.rfft2(t[0].astype(np.float64))),
                          s=(ny, nx))[np.ix_(matcher._iy, matcher._ix)]
    np.testing.assert_allclose(one, want1, atol=1e-5 * float(np.abs(want1).max()))
    # a shifted crop peaks at its shift: f = t moved by (dy, dx) puts the maximum at s = (dy, dx)
    dy, dx = 7, -4
    shifted = np.roll(t, (dy, dx), axis=(1, 2))
    score = matcher._corr(_spectra(shifted), _spectra(t))
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    assert (matcher._sy[0] + iy, matcher._sx[0] + ix) == (dy, dx)


def test_a_short_range_template_smaller_than_the_crop_still_matches(world) -> None:
    """max_range_m 15 m: the template is much smaller than the crop, every searched shift starts inside it, and the
    FFT must still hold the whole crop (a broadcast error otherwise)."""
    renderer, smap, _ = world
    matcher = ClassicalMatcher(ClassicalMatcherConfig(max_range_m=15.0), renderer.camera)
    true_en = np.array([WEST + 150.0, NORTH - 140.0])
    theta = math.radians(63.0)
    frame = GroundFrame(renderer.render((true_en[0], true_en[1], theta)), 0.0, renderer.camera)
    (res,) = matcher.match(frame, [_crop_at(smap, true_en, theta, 6.0, -4.0)])
    assert np.hypot(*(res.t - [6.0, -4.0])) < 1.0, res.t


def test_the_unsaturated_channel_matches_a_colour_world_and_an_unknown_channel_is_refused(world) -> None:
    renderer, smap, _ = world
    matcher = ClassicalMatcher(ClassicalMatcherConfig(grey="unsaturated"), renderer.camera)
    true_en = np.array([WEST + 150.0, NORTH - 140.0])
    theta = math.radians(63.0)
    frame = GroundFrame(renderer.render((true_en[0], true_en[1], theta)), 0.0, renderer.camera)
    (res,) = matcher.match(frame, [_crop_at(smap, true_en, theta, 6.0, -4.0)])
    assert np.hypot(*(res.t - [6.0, -4.0])) < 1.0, res.t
    with pytest.raises(MatcherError, match="classical.grey"):
        ClassicalMatcher(ClassicalMatcherConfig(grey="hue"), renderer.camera).match(
            frame, [_crop_at(smap, true_en, theta, 6.0, -4.0)])
