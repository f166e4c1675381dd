"""FG2-statistics emulator: a STATISTICAL MODEL of what FG2 returns on KITTI, not a matcher.

It never looks at an image. Given the true pose at the frame time (simulation or dataset ground truth) and each
crop's centre and heading, it draws the (R, t, w) FG2 would plausibly return, from FG2's published KITTI figures
and the failure modes the TACO paper describes (Sec. III-E). Use it to evaluate the fusion on image-less drives
(KITTI OXTS only) or to isolate the estimator from the matcher; never as a localiser on a vehicle.

Model (all parameters in `EmulatorConfig`; docs/matchers.md has the reasoning):
- capture: the true position lies within `capture_radius_m` (20 m) of the crop centre. Outside it ("miss") the
  answer is a uniformly random position in the crop, a uniformly random heading residual and a low weight
  w ~ U(0.01, miss_weight_max).
- inside, one of three outcomes:
  * nominal (probability 1 - lock - outlier): error magnitude ~ log-normal with mu = ln(median),
    sigma = sqrt(2 ln(mean / median)), so the median and mean are FG2's (0.51 / 0.75 m same-area, 4.15 /
    7.31 m cross-area). The direction is anisotropic: the unit vector of (N(0, 1), N(0, lateral_to_forward))
    in (forward, left), so lateral errors dominate 2:1 as in Sec. III-F, while the magnitude keeps its
    distribution exactly. Heading residual = true residual + N(0, yaw_noise_rad).
    w = clip(exp(-err / weight_scale_m) + N(0, weight_noise), 0.01, 1).
  * symmetric-structure lock (`symmetric_lock_rate`): the heading residual is off by +-90 or 180 degrees
    (plus noise), the error ~ U(0, capture radius), w ~ U(0.6, 0.95): the yaw gate (|psi_res| > 0.35) catches it.
  * silent outlier (`silent_outlier_rate`): heading residual as nominal, error ~ U(outlier_min_error_m, capture
    radius), w ~ U(0.3, 0.8): the gate cannot catch it.
  The published median/mean describe the nominal outcome; the failure modes come on top (with the default
  rates they raise the same-area mean by about 0.5 m).
- place (`place_share`, default 0): a nominal error's log-normal draw is split into a part shared by the place
  (a smooth random field over the ground at the camera's position, correlation length `place_length_m`) and a
  part of its own, keeping the marginal distribution. With 0 every answer is independent, even the crops of one
  frame; with a share, weak answers come in stretches, as a real matcher's do in a street it finds hard.
- lever arm: FG2 localises the camera, so the emulator answers with the CAMERA's true position (truth + the
  camera's (forward, left) offset from the reference point rotated by the true heading, `lever_fwd_left`) plus
  its noise; the capture radius is measured from the camera too. The Localiser takes the same lever arm off.
- determinism: each (frame, crop) draw uses its own numpy Generator seeded from (seed, round(t * 1000),
  crop index), so results depend only on the seed and the query, never on call order.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from taco_mav.config import EmulatorConfig
from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame, TruthFn
from taco_mav.errors import ConfigError
from taco_mav.geo import wrap_angle as _wrap


class Outcome(enum.Enum):
    """What kind of answer a draw is."""

    NOMINAL = "nominal"
    LOCK = "lock"
    OUTLIER = "outlier"
    MISS = "miss"


@dataclass(frozen=True)
class Draw:
    """One emulated answer. t: (forward, left) metres from the crop centre; err_m: |t - true t| (nan for a
    miss); psi: heading residual, rad (CCW); w: weight in (0, 1]."""

    outcome: Outcome
    t: np.ndarray
    err_m: float
    psi: float
    w: float


def lognormal_params(median: float, mean: float) -> tuple[float, float]:
    """(mu, sigma) of the log-normal with the given median and mean (mean >= median > 0), metres."""
    if not (median > 0 and mean >= median):
        raise ConfigError(f"emulator: need mean_error_m >= median_error_m > 0, got median {median}, mean {mean}")
    return math.log(median), math.sqrt(2.0 * math.log(mean / median))


def frame_rng(seed: int, t: float, index: int) -> np.random.Generator:
    """The Generator for one (frame time, crop index) under a seed."""
    t_ms = int(round(t * 1000.0)) % (1 << 63)
    return np.random.default_rng([int(seed) % (1 << 63), t_ms, int(index)])


class PlaceField:
    """A smooth standard-normal random field over the ground, z(E, N) (UTM metres): how hard the place is for the
    matcher. Random Fourier features of a Gaussian kernel, so corr(z(p), z(p + d)) = exp(-|d|^2 / (2 L^2)) with
    L = length_m; deterministic per seed and independent of query order."""

    def __init__(self, seed: int, length_m: float, features: int = 64) -> None:
        rng = np.random.default_rng([int(seed) % (1 << 63), 0x91ACE])
        self.omega = rng.normal(0.0, 1.0 / length_m, size=(features, 2))  # rad/m
        self.phase = rng.uniform(0.0, 2.0 * math.pi, size=features)
        self.scale = math.sqrt(2.0 / features)

    def __call__(self, east: float, north: float) -> float:
        """z at a ground position, UTM metres; N(0, 1) over the fields a seed draws."""
        return self.scale * float(np.cos(self.omega @ np.array([east, north]) + self.phase).sum())


def draw(rng: np.random.Generator, cfg: EmulatorConfig, t_true: np.ndarray, psi_true: float,
         crop_half_m: float, cross_area: bool = False, place_z: float = 0.0) -> Draw:
    """One emulated FG2 answer for a crop. t_true: true vehicle position in the crop's (forward, left) frame,
    metres; psi_true: true heading minus crop heading, rad; crop_half_m: half the crop side, metres; place_z: the
    place field at the camera (enters a nominal error's log with the weight cfg.place_share)."""
    distance = float(np.hypot(*t_true))
    if distance > cfg.capture_radius_m:
        t = rng.uniform(-crop_half_m, crop_half_m, size=2)
        return Draw(Outcome.MISS, t, float("nan"), float(rng.uniform(-math.pi, math.pi)),
                    float(rng.uniform(0.01, cfg.miss_weight_max)))
    median, mean = ((cfg.cross_area_median_error_m, cfg.cross_area_mean_error_m) if cross_area
                    else (cfg.median_error_m, cfg.mean_error_m))
    u = rng.random()
    direction = rng.normal(0.0, 1.0, size=2) * np.array([1.0, cfg.lateral_to_forward])
    direction /= max(float(np.hypot(*direction)), 1e-12)
    psi = psi_true + rng.normal(0.0, cfg.yaw_noise_rad)
    if u < cfg.symmetric_lock_rate:
        outcome = Outcome.LOCK
        psi += float(rng.choice([math.pi / 2, -math.pi / 2, math.pi]))
        err = rng.uniform(0.0, cfg.capture_radius_m)
        w = rng.uniform(0.6, 0.95)
    elif u < cfg.symmetric_lock_rate + cfg.silent_outlier_rate:
        outcome = Outcome.OUTLIER
        err = rng.uniform(min(cfg.outlier_min_error_m, cfg.capture_radius_m), cfg.capture_radius_m)
        w = rng.uniform(0.3, 0.8)
    else:
        outcome = Outcome.NOMINAL
        mu, sigma = lognormal_params(median, mean)
        if cfg.place_share > 0.0:  # the same marginal log-normal, part of it shared by the place
            z = math.sqrt(cfg.place_share) * place_z + math.sqrt(1.0 - cfg.place_share) * rng.standard_normal()
            err = math.exp(mu + sigma * z)
        else:
            err = rng.lognormal(mu, sigma)
        w = math.exp(-err / cfg.weight_scale_m) + rng.normal(0.0, cfg.weight_noise)
    w = float(np.clip(w, 0.01, 1.0))
    return Draw(outcome, np.asarray(t_true, float) + err * direction, float(err), _wrap(float(psi)), w)


class EmulatorMatcher:
    """Matcher-shaped FG2 statistics (see the module docstring). truth(t) -> (E, N, theta): the true absolute
    UTM metres and ENU heading (rad) at time t of the vehicle reference point. cross_area selects FG2's
    cross-area error figures. seed overrides cfg.seed. lever_fwd_left: the camera's offset from the reference
    point, body (forward, left) metres (profile camera.position_frd_m as (x, -y))."""

    name = "emulator"
    needs_true_pose = True

    def __init__(self, cfg: EmulatorConfig, truth: TruthFn, cross_area: bool = False, seed: int | None = None,
                 lever_fwd_left: tuple[float, float] = (0.0, 0.0)) -> None:
        lognormal_params(cfg.median_error_m, cfg.mean_error_m)
        lognormal_params(cfg.cross_area_median_error_m, cfg.cross_area_mean_error_m)
        if cfg.symmetric_lock_rate + cfg.silent_outlier_rate > 1.0:
            raise ConfigError("emulator: symmetric_lock_rate + silent_outlier_rate must be <= 1")
        self.cfg = cfg
        self.truth = truth
        self.cross_area = cross_area
        self.seed = cfg.seed if seed is None else int(seed)
        self.lever = (float(lever_fwd_left[0]), float(lever_fwd_left[1]))
        self.place = PlaceField(self.seed, cfg.place_length_m)
        self.last_draws: list[Draw] = []  # the draws behind the last match() (for diagnostics and tests)

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        """One MatchResult per crop; frame.image is ignored (may be empty)."""
        start = time.perf_counter()
        E, N, theta = self.truth(frame.t)
        (lf, ll), c0, s0 = self.lever, math.cos(theta), math.sin(theta)
        E, N = E + c0 * lf - s0 * ll, N + s0 * lf + c0 * ll  # the camera's true ground position
        draws: list[Draw] = []
        place_z = self.place(E, N) if self.cfg.place_share > 0.0 else 0.0
        for i, crop in enumerate(crops):
            d = np.array([E - crop.centre_utm[0], N - crop.centre_utm[1]])
            ct, st = math.cos(crop.heading), math.sin(crop.heading)
            t_true = np.array([d[0] * ct + d[1] * st, -d[0] * st + d[1] * ct])
            half = 0.5 * crop.image.shape[0] * crop.m_per_px if crop.image.size else self.cfg.capture_radius_m
            draws.append(draw(frame_rng(self.seed, frame.t, i), self.cfg, t_true, _wrap(theta - crop.heading),
                              half, self.cross_area, place_z))
        self.last_draws = draws
        elapsed = (time.perf_counter() - start) / max(len(crops), 1)
        out = []
        for dr in draws:
            c, s = math.cos(dr.psi), math.sin(dr.psi)
            out.append(MatchResult(R=np.array([[c, -s], [s, c]]), t=dr.t, w=dr.w, elapsed_s=elapsed))
        return out
