"""Classical CPU matcher: inverse perspective mapping + rotation search x masked NCC by FFT (paper Sec. III-C).

Pipeline per trigger (one ground frame, K heading-up crops):
1. the frame's grey image is projected ONCE to a bird's-eye view (BEV, `taco_mav.cvgl.ipm`) at the matcher's
   resolution, vehicle at the bottom-centre pixel, forward = image-up. Pixels the IPM cannot represent are
   masked (`taco_mav.cvgl.masks`: vertical structure found in the camera image, the ego vehicle's rows; the
   sky and beyond-range rays are outside the BEV's own mask).
2. the BEV is rotated about the vehicle pixel by each candidate residual psi (CCW positive) in a grid over
   +-rotation_range and described (`taco_mav.cvgl.descriptors`: "orientation", gradient orientation in
   doubled-angle form, 2 channels; or "lcn", grey-level local contrast normalisation, 1 channel); every rotated
   template is restricted to a common mask (the intersection of the rotated view wedges) less the trigger's
   masked pixels (rotated with it), normalised (zero mean per channel, unit energy), and Fourier-transformed
   once; the FFTs are reused for every crop.
3. each crop is converted to grey, resampled to the matcher's resolution, described and transformed once; the
   zero-normalised cross-correlation of the stacked channels over all shifts is num / sqrt(local variance), the
   local sums coming from FFT correlations with the common mask (exact where the template lies wholly on the
   crop; partial overlaps down to `min_overlap` are scored with the template energy prorated).
4. the best rotation is refined at +-step/2 and by a parabola through the three peak scores; the peak position
   by a 2-D parabolic fit. w = a logistic of the peak-to-sidelobe ratio (PSR), per descriptor
   (`W_CALIBRATION`), that rises with the probability of a correct match (`psr_weight`).

Output per crop (see `taco_mav.cvgl.base`): R = rotation by psi (CCW positive), t = vehicle (forward, left)
metres from the crop centre in the crop frame, w in (0, 1].

docs/matchers.md describes the matcher and its settings; docs/results.md has the measurements behind its
constants (the PSR -> w calibration per descriptor, the FFT's cost) with the commit and command of each."""

from __future__ import annotations

import logging
import math
import time
from typing import Sequence

import cv2
import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import ClassicalMatcherConfig
from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.cvgl.descriptors import DESCRIPTORS, check_grey, describe, grey_channel
from taco_mav.cvgl.ipm import BevProjector
from taco_mav.cvgl.masks import MaskOptions, image_mask
from taco_mav.errors import MatcherError

log = logging.getLogger(__name__)

__all__ = ["ClassicalMatcher", "W_CALIBRATION", "psr_weight"]

_EPS = 1e-6

# PSR -> w logistic: midpoint (w = 0.5) and scale, PSR units; correct = fix error < 3 m. 6.5 / 0.5 lies between
# the maximum-likelihood fits on a synthetic world's crops and on the bench's textured mosaic (docs/results.md,
# "The classical matcher's PSR -> w calibration"). The profile's classical.psr_at_half_weight /
# psr_logistic_scale override W_CALIBRATION below when set.
PSR_AT_HALF_WEIGHT = 6.5
PSR_LOGISTIC_SCALE = 0.5

# (midpoint, scale) of the PSR -> w logistic per descriptor, used when the profile leaves them unset. Both
# descriptors take 6.5 / 0.5: for orientation it is within 0.02 in log-loss of the pooled maximum-likelihood fit
# on worlds that are not those of the figures in docs/matchers.md (docs/results.md). w cannot make the fix noise
# honest for correct matches: at w = 1 the paper's mapping (Sec. III-F) says 1.5 m forward, 3 m lateral, several
# times their errors; docs/matchers.md has the NIS this gives.
W_CALIBRATION: dict[str, tuple[float, float]] = {
    "lcn": (PSR_AT_HALF_WEIGHT, PSR_LOGISTIC_SCALE),
    "orientation": (PSR_AT_HALF_WEIGHT, PSR_LOGISTIC_SCALE),
}


def psr_weight(psr: float, psr_at_half_weight: float = PSR_AT_HALF_WEIGHT,
               scale: float = PSR_LOGISTIC_SCALE) -> float:
    """Match weight in [_EPS, 1] from a peak-to-sidelobe ratio: 1 / (1 + exp(-(psr - psr_at_half_weight) / scale)),
    monotone in the probability that the match is correct (calibration: PSR_AT_HALF_WEIGHT)."""
    z = (psr - psr_at_half_weight) / scale
    w = 1.0 / (1.0 + math.exp(-z)) if z > -700.0 else 0.0
    return float(min(max(w, _EPS), 1.0))


def _spectra(planes: np.ndarray) -> np.ndarray:
    """The DFT of each float32 plane of (ny, nx) or (C, ny, nx), in OpenCV's packed layout for real input (CCS:
    the same shape and dtype, the spectrum's independent half), which `cv2.mulSpectrums` multiplies and
    `cv2.idft` inverts. OpenCV's FFT rather than scipy's: the daemon then never imports scipy.fft (with
    scipy.special, which it pulls in, 8 MB of a companion's memory) at about scipy's cost per call
    (docs/results.md); the correlations agree with a float64 FFT's to float32 rounding (tests/test_classical.py)."""
    if planes.ndim == 2:
        return cv2.dft(planes)
    return np.stack([cv2.dft(p) for p in planes])


def _parabola(ym: float, y0: float, yp: float) -> float:
    """Vertex offset in (-0.5, 0.5) of the parabola through (-1, ym), (0, y0), (1, yp)."""
    den = ym - 2.0 * y0 + yp
    if not np.isfinite(den) or den >= -1e-12:
        return 0.0
    return float(np.clip(0.5 * (ym - yp) / den, -0.5, 0.5))


class ClassicalMatcher:
    """Matcher protocol implementation (`taco_mav.cvgl.base.Matcher`) for CPU-only use and for tests."""

    name = "classical"
    needs_true_pose = False

    def __init__(self, cfg: ClassicalMatcherConfig, camera: GroundCamera, *, descriptor: str | None = None,
                 masks: MaskOptions | None = None) -> None:
        """descriptor, masks: override the profile's `descriptor` and `mask_vertical` / `ego_mask_rows`."""
        self.cfg = cfg
        self.camera = camera
        self.descriptor = cfg.descriptor if descriptor is None else descriptor
        if self.descriptor not in DESCRIPTORS:
            raise MatcherError(f"classical matcher: descriptor {self.descriptor!r} is not one of "
                               f"{', '.join(DESCRIPTORS)} (profile key classical.descriptor)")
        check_grey(cfg.grey)
        self.masks = MaskOptions(vertical=cfg.mask_vertical, ego_rows=cfg.ego_mask_rows,
                                 vegetation=cfg.mask_vegetation,
                                 exg_min=cfg.vegetation_exg_min) if masks is None else masks
        mid, scale = W_CALIBRATION[self.descriptor]
        self.psr_at_half_weight = mid if cfg.psr_at_half_weight is None else cfg.psr_at_half_weight
        self.psr_logistic_scale = scale if cfg.psr_logistic_scale is None else cfg.psr_logistic_scale
        m = cfg.bev_m_per_px
        self.m_per_px = m
        n_half = max(0, int(math.floor(cfg.rotation_range_rad / cfg.rotation_step_rad + 1e-9)))
        self.angles = np.arange(-n_half, n_half + 1) * cfg.rotation_step_rad
        # Template canvas: the view wedge within max_range, widened for the largest rotation; capped by
        # bev_size_px along each axis.
        probe = BevProjector(camera, (2 * cfg.bev_size_px + 1, cfg.bev_size_px), m, cfg.max_range_m, levels=1)
        fl = np.c_[probe.fwd_m[probe.mask], probe.left_m[probe.mask]]
        amax = float(np.max(np.abs(self.angles))) if len(self.angles) else 0.0
        lat = 0.0
        fwd_max = 0.0
        for a in (-amax, 0.0, amax):
            c, s = math.cos(a), math.sin(a)
            lat = max(lat, float(np.abs(s * fl[:, 0] + c * fl[:, 1]).max()))
            fwd_max = max(fwd_max, float((c * fl[:, 0] - s * fl[:, 1]).max()))
        half_w = min(int(math.ceil(lat / m)) + 2, cfg.bev_size_px // 2)
        height = min(int(math.ceil(fwd_max / m)) + 3, cfg.bev_size_px)
        self._bev = BevProjector(camera, (2 * half_w + 1, height), m, cfg.max_range_m)
        self.vehicle_px = self._bev.vehicle_px
        self._base = self._bev.mask.astype(np.float32)
        common = self._common(self._base)
        self._mask, self._mask_n = common, float(common.sum())
        if self._mask_n < 100:
            raise MatcherError(f"classical matcher: only {self._mask_n:.0f} BEV pixels remain under the rotation "
                               "search; reduce rotation_range_rad or enlarge bev_size_px/max_range_m")
        self._sigma_px = max(cfg.lcn_sigma_m / m, 0.5)
        self._fft_shape: tuple[int, int] | None = None
        self._crop_px: int | None = None
        self._mask_fc: np.ndarray | None = None
        self.last_psr: list[float] = []  # peak-to-sidelobe ratio of each crop of the last match() call
        self.last_mask_fraction = 1.0  # share of the static template mask left by the last trigger's masks
        log.debug("classical matcher: %s descriptor, template %dx%d px at %.2f m/px, %d angles, %.0f mask px",
                  self.descriptor, common.shape[1], common.shape[0], m, len(self.angles), self._mask_n)

    def _common(self, mask: np.ndarray) -> np.ndarray:
        """The intersection of `mask` (float32 0/1 on the template canvas) rotated by every searched angle."""
        common = mask.copy()
        for a in self.angles:
            common = np.minimum(common, self._rotate(mask, a, cv2.INTER_NEAREST))
        return common

    # ------------------------------------------------------------------ geometry helpers
    def _rotate(self, img: np.ndarray, angle: float, interp: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Rotate a template-canvas image by `angle` rad CCW (as displayed) about the vehicle pixel."""
        if angle == 0.0:
            return img
        M = cv2.getRotationMatrix2D(self.vehicle_px, math.degrees(angle), 1.0)
        h, w = img.shape[:2]
        return cv2.warpAffine(img, M, (w, h), flags=interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def _setup_fft(self, crop_px: int) -> None:
        """FFT size and searched shift range for crops of `crop_px` pixels at the matcher's resolution."""
        h, w = self._mask.shape
        u0, v0 = self.vehicle_px
        c = (crop_px - 1) / 2.0
        r = min(self.cfg.search_radius_m / self.m_per_px, c)
        # template top-left shift s: vehicle crop pixel = s + (u0, v0); vehicle within c +- r.
        self._sx = (int(math.ceil(c - r - u0)), int(math.floor(c + r - u0)))
        self._sy = (int(math.ceil(c - r - v0)), int(math.floor(c + r - v0)))
        # the crop must fit as well: a template much smaller than the crop (a short max_range_m) searches
        # shifts that all start inside it (sx[0] > 0), and crop_px - sx[0] alone is then narrower than the crop
        ny = cv2.getOptimalDFTSize(max(self._sy[1] + h, crop_px - self._sy[0], crop_px))
        nx = cv2.getOptimalDFTSize(max(self._sx[1] + w, crop_px - self._sx[0], crop_px))
        self._fft_shape = (ny, nx)
        self._crop_px = crop_px
        self._mask_fc = self._mask_spectrum(self._mask)
        self._n_whole: np.ndarray | None = None  # the overlap counts of a crop valid everywhere (`_denominator`)
        self._iy = np.arange(self._sy[0], self._sy[1] + 1) % ny
        self._ix = np.arange(self._sx[0], self._sx[1] + 1) % nx

    def _mask_spectrum(self, mask: np.ndarray) -> np.ndarray:
        """Spectrum (`_spectra`) of a template-canvas mask at the current FFT size."""
        pad = np.zeros(self._fft_shape, np.float32)  # type: ignore[arg-type]
        pad[: mask.shape[0], : mask.shape[1]] = mask
        return _spectra(pad)

    def _template_fft(self, bev: np.ndarray, angle: float, view: np.ndarray) -> np.ndarray:
        """Spectra (`_spectra`, (C, ny, nx)) of the rotated template's descriptor channels on the common
        mask less the trigger's hidden pixels, each zero-mean, jointly of unit energy. lcn: `bev` holds the
        channels of the unrotated BEV, which are rotated (a scalar field); orientation: `bev` is the grey BEV,
        rotated and then described (its channels are directions), with `view` (the BEV's usable pixels: in
        view, not masked) rotated alike."""
        seen = self._rotate(view, angle, cv2.INTER_NEAREST) if view is not self._base else None
        if self.descriptor == "lcn":
            chans = np.stack([self._rotate(c, angle) for c in bev])
        else:
            chans = describe(self.descriptor, self._rotate(bev, angle),
                             self._rotate(view, angle, cv2.INTER_NEAREST) if seen is None else seen, self._sigma_px)
        # the common mask, less what this trigger's masks hide (rotated with the template, not intersected over
        # the rotations: the local statistics of the crop keep the common mask, a slight underestimate of the
        # score where much is hidden, the same for every shift)
        m = self._mask if seen is None else self._mask * seen
        t = chans * m[None]
        t -= m[None] * (t.sum(axis=(1, 2)) / max(float(m.sum()), 1.0))[:, None, None]
        t /= math.sqrt(float((t * t).sum())) + _EPS
        ny, nx = self._fft_shape  # type: ignore[misc]
        pad = np.zeros((t.shape[0], ny, nx), np.float32)
        pad[:, : t.shape[1], : t.shape[2]] = t
        return _spectra(pad)

    def _corr(self, spec: np.ndarray, tmpl: np.ndarray) -> np.ndarray:
        """Correlation over the searched shifts (rows sy, cols sx) of a crop with a template, from their spectra
        (`_spectra`); (C, ...) spectra are correlated channel by channel and summed."""
        if spec.ndim == 3:
            prod = cv2.mulSpectrums(spec[0], tmpl[0], 0, conjB=True)
            for s, t in zip(spec[1:], tmpl[1:]):
                prod += cv2.mulSpectrums(s, t, 0, conjB=True)
        else:
            prod = cv2.mulSpectrums(spec, tmpl, 0, conjB=True)
        full = cv2.idft(prod, flags=cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
        return full.take(self._iy, axis=0).take(self._ix, axis=1)  # a third of np.ix_'s time

    # ------------------------------------------------------------------ matching
    def _crop_px_of(self, crop: Crop) -> int:
        """Side of a crop at the matcher's resolution, pixels; MatcherError for a crop that is not square RGB."""
        img = crop.image
        if img.ndim != 3 or img.shape[0] != img.shape[1]:
            raise MatcherError(f"classical matcher: crop must be square RGB (S, S, 3), got {img.shape}")
        return max(8, int(round(img.shape[0] * crop.m_per_px / self.m_per_px)))

    def _prepare_crop(self, crop: Crop, Sw: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Crop -> (spectra (C, ...) of its descriptor channels, spectrum of the channels' summed squares,
        spectrum of its valid pixels, None when it is valid everywhere) at the matcher's resolution, where it is
        Sw pixels a side (`_crop_px_of`) and the FFT is set up for that size."""
        img = crop.image
        S = img.shape[0]
        grey = grey_channel(img, self.cfg.grey)
        valid = (img.max(axis=2) > 0) if crop.valid_fraction < 1.0 else None
        if Sw != S:
            grey = cv2.resize(grey, (Sw, Sw), interpolation=cv2.INTER_AREA)
            if valid is not None:
                valid = cv2.resize(valid.astype(np.float32), (Sw, Sw), interpolation=cv2.INTER_AREA) > 0.5
        vm = None if valid is None else valid.astype(np.float32)
        f = describe(self.descriptor, grey.astype(np.float32), vm, self._sigma_px)
        C = f.shape[0]
        ny, nx = self._fft_shape  # type: ignore[misc]
        planes = C + 1 if vm is None else C + 2
        pads = np.zeros((planes, ny, nx), np.float32)
        pads[:C, :Sw, :Sw] = f
        pads[C, :Sw, :Sw] = (f * f).sum(axis=0)
        if vm is not None:
            pads[C + 1, :Sw, :Sw] = vm
        specs = _spectra(pads)
        return specs[:C], specs[C], None if vm is None else specs[C + 1]

    def _overlap(self, valid: np.ndarray | None) -> np.ndarray:
        """Pixels of the template mask on the crop's valid pixels, over the searched shifts, from the spectrum
        of the valid pixels (None: valid everywhere, the same for every such crop of this size: computed once)."""
        if valid is not None:
            return np.maximum(self._corr(valid, self._mask_fc), 0.0)
        if self._n_whole is None:
            ones = np.zeros(self._fft_shape, np.float32)  # type: ignore[arg-type]
            ones[: self._crop_px, : self._crop_px] = 1.0
            self._n_whole = np.maximum(self._corr(_spectra(ones), self._mask_fc), 0.0)
        return self._n_whole

    def _denominator(self, prepared: tuple[np.ndarray, np.ndarray, np.ndarray | None]) -> np.ndarray:
        """NCC denominator over the searched shifts: sqrt(local variance of the crop's channels under the
        template mask x prorated template energy); inf where the overlap is below min_overlap."""
        chans, sq, valid = prepared
        mask_fc = self._mask_fc
        n = self._overlap(valid)
        s2 = self._corr(sq, mask_fc)
        nn = np.maximum(n, 1.0)
        var = s2
        for c in chans:
            s1 = self._corr(c, mask_fc)
            var = var - s1 * s1 / nn
        var = np.maximum(var, 0.0)
        # sum f t is compared with sqrt(var * sum_overlap t^2) ~ sqrt(var * n / N_mask)
        denom = np.sqrt(var * n / self._mask_n) + 1e-3
        denom[n < self.cfg.min_overlap * self._mask_n] = np.inf
        return denom

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        """One MatchResult per crop, in order (contract in `taco_mav.cvgl.base`)."""
        t_start = time.perf_counter()
        if not crops:
            return []
        image = frame.image
        grey = grey_channel(image, self.cfg.grey) if image.ndim == 3 else image
        bev, _ = self._bev.project(grey)
        view = self._base
        hidden = image_mask(image, self.camera, self.masks)
        if hidden is not None:
            occ, _ = self._bev.project(hidden.astype(np.float32))
            view = self._base * (occ < 0.25).astype(np.float32)
        # one FFT size for the trigger (a crop of another size would re-plan it under the cached templates); each
        # crop's spectra are computed when it is scored, not all at once: the matcher thread's allocator keeps the
        # high-water mark of what a trigger holds (docs/companion.md)
        sizes = {self._crop_px_of(c) for c in crops}
        if len(sizes) > 1:
            raise MatcherError(f"classical matcher: a trigger's crops must share one size at {self.m_per_px} m/px, "
                               f"got {sorted(sizes)} px")
        (crop_px,) = sizes
        self.last_mask_fraction = float((self._mask * view).sum()) / self._mask_n
        if self.last_mask_fraction < self.masks.min_view_fraction:
            # the masks leave too little ground to match: no answer (w at its floor), not a guess
            self.last_psr = [0.0] * len(crops)
            elapsed = time.perf_counter() - t_start
            return [MatchResult(np.eye(2), np.zeros(2), _EPS, elapsed / len(crops)) for _ in crops]
        if self._crop_px != crop_px:
            self._setup_fft(crop_px)
        if self.descriptor == "lcn":
            bev = describe("lcn", bev, view, self._sigma_px)
        cache: dict[float, np.ndarray] = {}

        def tmpl(a: float) -> np.ndarray:
            key = round(a, 9)
            if key not in cache:
                cache[key] = self._template_fft(bev, a, view)
            return cache[key]

        h = 0.5 * self.cfg.rotation_step_rad
        results: list[MatchResult] = []
        psrs: list[float] = []
        for crop in crops:
            prep = self._prepare_crop(crop, crop_px)
            spec, denom = prep[0], self._denominator(prep)
            maps: dict[float, np.ndarray] = {}

            def score_at(a: float) -> np.ndarray:
                key = round(a, 9)
                if key not in maps:
                    maps[key] = self._corr(spec, tmpl(a)) / denom
                return maps[key]

            peaks = {round(float(a), 9): float(score_at(float(a)).max()) for a in self.angles}
            a_best = max(peaks, key=peaks.get)
            if not np.isfinite(peaks[a_best]):
                results.append(MatchResult(R=np.eye(2), t=np.zeros(2), w=_EPS))
                psrs.append(0.0)
                continue
            # Refine: +-step/2, then +-step/4 around the best so far, then a parabola through the last three.
            d = h
            while d > 0 and len(self.angles) > 1 and d >= 0.249 * self.cfg.rotation_step_rad:
                for a in (a_best - d, a_best + d):
                    peaks[round(a, 9)] = float(score_at(a).max())
                a_best = max(peaks, key=peaks.get)
                d *= 0.5
            score = score_at(a_best)
            peak = float(score.max())
            iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
            d *= 2.0
            lo_a, hi_a = round(a_best - d, 9), round(a_best + d, 9)
            if d > 0 and lo_a in maps and hi_a in maps:
                a_fit = a_best + d * _parabola(float(maps[lo_a][iy, ix]), peak, float(maps[hi_a][iy, ix]))
            else:
                a_fit = a_best
            result, psr = self._result(score, peak, a_fit, crop)
            results.append(result)
            psrs.append(psr)
        self.last_psr = psrs
        elapsed = time.perf_counter() - t_start
        return [MatchResult(r.R, r.t, r.w, elapsed / len(crops)) for r in results]

    def _result(self, score: np.ndarray, peak: float, angle: float, crop: Crop) -> tuple[MatchResult, float]:
        """Sub-pixel peak, PSR weight and the crop-frame translation for one crop's best score map; also the
        PSR itself."""
        iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
        H, W = score.shape
        dy = _parabola(score[iy - 1, ix], peak, score[iy + 1, ix]) if 0 < iy < H - 1 else 0.0
        dx = _parabola(score[iy, ix - 1], peak, score[iy, ix + 1]) if 0 < ix < W - 1 else 0.0
        sy = self._sy[0] + iy + dy
        sx = self._sx[0] + ix + dx
        u0, v0 = self.vehicle_px
        c = (self._crop_px - 1) / 2.0  # type: ignore[operator]
        veh_u, veh_v = sx + u0, sy + v0
        t = np.array([(c - veh_v) * self.m_per_px, (c - veh_u) * self.m_per_px])
        excl = max(1, int(round(self.cfg.psr_exclusion_m / self.m_per_px)))
        finite = np.isfinite(score)
        finite[max(0, iy - excl): iy + excl + 1, max(0, ix - excl): ix + excl + 1] = False
        side = score[finite]
        psr = float((peak - side.mean()) / (side.std() + _EPS)) if side.size > 10 else 0.0
        psr = max(psr, 0.0)
        w = psr_weight(psr, self.psr_at_half_weight, self.psr_logistic_scale)
        ca, sa = math.cos(angle), math.sin(angle)
        return MatchResult(R=np.array([[ca, -sa], [sa, ca]]), t=t, w=w), psr
