"""Bench section: the matcher and the answer check on real imagery, as the daemon runs them.

Every set under the real-pairs folder (`taco_mav.datasets.real_pairs`; default `../shared/data/real_pairs`, or
TACO_REAL_PAIRS, or `--real-pairs DIR`) is scored: from each panorama, pinhole front views are cut at
VIEW_BEARINGS_DEG (turned by a seeded angle per place) and VIEW_FOVS_DEG; a pinhole set's frames are used as
they are. The place's aerial is written as a north-up GeoTIFF and opened as the daemon opens its map
(`SatelliteMap`). Each view is asked as a taco+ trigger asks: the profile's 5-crop cross (arm `cross_arm` at the
profile's trigger_sigma_m) around a prior PRIOR_OFFSET_M off the truth in a seeded direction, the query heading
within +-HEADING_NOISE_DEG of the truth, through `FixService` with the profile's matcher, and the answers judged by
`taco_mav.core.answer_check.check_answer` with the profile's `answer` parameters: the rule every mode applies
before an answer can become a fix. The wrong-map control asks the same view against another place's aerial.

The same harness runs on synthetic pairs made the same way (a rendered view of a seeded textured mosaic, its
aerial resampled to the real sets' scale): the `synthetic_pairs_*` keys are the harness's own check.

Keys (real_* and synthetic_pairs_*): within_3m_share (the best answer within SUCCESS_M of the camera),
median_error_m, median_prior_error_m, accepted_share, accepted_precision (accepted answers within SUCCESS_M /
accepted; None when nothing is accepted), wrong_map_accepted_share, w_auc (rank AUC of the best answer's w,
true map against the wrong map), tries, and for real sets real_sets / real_places.
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from taco_mav.bench.classical import textured_mosaic, write_geotiff
from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import Estimator, Profile, load_profile
from taco_mav.core.answer_check import credible, supported
from taco_mav.core.gate import yaw_residual
from taco_mav.core.plus.search import consensus
from taco_mav.core.plus.search import cross_arm
from taco_mav.core.search import body_to_world, cross_offsets, fix_position
from taco_mav.core.types import FixQuery, MatchResult
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.registry import make_matcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.cvgl.service import profile_service
from taco_mav.datasets.real_pairs import RealSet, find_sets, pinhole_view, read_rgb
from taco_mav.errors import DataError

log = logging.getLogger(__name__)

SUCCESS_M = 3.0  # an answer within this of the camera is right (the synthetic bench's success)
PRIOR_OFFSET_M = (4.0, 8.0)  # the prior's distance from the truth, uniform (a lost taco+'s prior)
HEADING_NOISE_DEG = 3.0  # the query heading's error, uniform within +-
VIEW_BEARINGS_DEG = (0.0, 90.0, 180.0, 270.0)  # per place, turned by a seeded angle
VIEW_FOVS_DEG = (60.0, 90.0)  # horizontal fields of view cut from a panorama (a rover camera's 60-100 deg)
VIEW_PITCH_DEG = 6.0  # the cut views' down-pitch (a rover's forward camera: the profiles' 0.1 rad)
VIEW_WIDTH_PX = 320
VIEW_ASPECT = 0.75  # height / width
WEST, NORTH = 500_000.0, 5_430_000.0  # the aerial's top-left corner as written, UTM metres (any will do)
DEFAULT_PROFILE = "ardupilot_rover"
SYNTHETIC_PLACES = 8
SYNTHETIC_M_PER_PX = 0.5711  # the synthetic pairs' aerial scale: the CVACT set's
SYNTHETIC_CAMERA_HEIGHT_M = 2.5


def default_root() -> Path:
    """TACO_REAL_PAIRS, else ../shared/data/real_pairs beside the checkout (as the tests find KITTI)."""
    env = os.environ.get("TACO_REAL_PAIRS")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "real_pairs"


@dataclass(frozen=True)
class TriggerOutcome:
    """One trigger's outcome: the best answer's (highest w) distance from the camera (m) and w, the trigger's
    chance level (decoys' w; None without decoys), whether a fix was made and its distance from the camera (m;
    nan when none)."""

    error_m: float
    w: float
    null_w: float | None
    accepted: bool
    fix_error_m: float


@dataclass(frozen=True)
class Try:
    """One asked view: where it was (place, view), the prior's distance from the camera (m), the verdict on its
    own map and on another place's (the wrong-map control)."""

    place: str
    view: str
    prior_error_m: float
    own: TriggerOutcome
    wrong: TriggerOutcome


@dataclass(frozen=True)
class View:
    """A ground view: RGB image, its camera, the compass bearing it faces (deg)."""

    image: np.ndarray
    camera: GroundCamera
    bearing_deg: float
    name: str


def _views(rset: RealSet, image: np.ndarray, heading_deg: float | None, rng: np.random.Generator) -> list[View]:
    if not rset.is_panorama:
        g = rset.ground
        K = np.array([[g["fx"], 0.0, g["cx"]], [0.0, g["fy"], g["cy"]], [0.0, 0.0, 1.0]], float)
        cam = GroundCamera(K, int(g["width"]), int(g["height"]), rset.camera_height_m, math.radians(g["pitch_deg"]))
        return [View(image, cam, float(heading_deg or 0.0), "frame")]
    turn = float(rng.uniform(0.0, 90.0))
    out = []
    for fov in VIEW_FOVS_DEG:
        for b in VIEW_BEARINGS_DEG:
            bearing = (b + turn) % 360.0
            img, cam = pinhole_view(image, rset.ground, bearing, fov, VIEW_WIDTH_PX,
                                    int(round(VIEW_WIDTH_PX * VIEW_ASPECT)), VIEW_PITCH_DEG, rset.camera_height_m)
            out.append(View(img, cam, bearing, f"b{bearing:.0f}_f{fov:.0f}"))
    return out


class _Asker:
    """Asks one view against one map as a taco+ trigger does, and judges the answers."""

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self.arm = cross_arm(profile.plus.trigger_sigma_m, profile.plus)
        self.lever = np.zeros(2)  # the views are taken at the camera: no lever arm
        self._matchers: dict[tuple, Any] = {}

    def matcher(self, cam: GroundCamera) -> Any:
        key = (cam.width, cam.height, float(cam.K[0, 0]), cam.mount_height_m, cam.pitch_rad)
        if key not in self._matchers:
            self._matchers[key] = make_matcher(self.profile, camera=cam)
        return self._matchers[key]

    def ask(self, view: View, smap: SatelliteMap, truth_en: np.ndarray, prior_en: np.ndarray,
            heading: float) -> TriggerOutcome:
        """A query at prior_en (absolute UTM, m) with the ENU heading (rad), judged as the profile's mode judges
        an answer where no gate against the track stands: taco+ while lock is lost (the shipped profiles recover
        without an innovation gate, plus.recover_chi2_gate 0: what a relocalisation faces), with plus.recover_w_min,
        the yaw gate, the answer check (core/answer_check.py) and the consensus; paper mode with the yaw gate and
        the check. truth_en: the camera's UTM position."""
        p = self.profile
        offsets = cross_offsets(self.arm, p.trigger.multi_crop)
        centres = prior_en[None, :] + body_to_world(heading, offsets)
        query = FixQuery(0, 0.0, prior_en, heading, offsets, centres, 0.0, "covariance")
        service = profile_service(self.matcher(view.camera), smap, np.zeros(2), p)
        results: list[MatchResult | None] = service.answer(query, GroundFrame(view.image, 0.0, view.camera))
        xy = np.full((len(results), 2), np.nan)
        psi = np.full(len(results), np.nan)
        w = np.zeros(len(results))
        for k, r in enumerate(results):
            if r is not None:
                xy[k] = fix_position(centres[k], heading, r.t, self.lever)
                psi[k] = yaw_residual(r.R)
                w[k] = r.w
        finite = np.isfinite(xy).all(axis=1)
        usable = finite.copy()
        if p.gate.enabled:
            usable &= np.abs(np.nan_to_num(psi)) <= p.gate.yaw_residual_max_rad
        fix = np.full(2, np.nan)
        if p.estimator is Estimator.TACO_PLUS:  # as taco+ while lock is lost: recover_w_min, the check, consensus
            usable &= (w >= p.plus.recover_w_min) & credible(results, p.answer)
            c = consensus(np.nan_to_num(xy), w, usable, p.plus.consensus_radius_m, p.plus.consensus_weight_power)
            if c is not None and supported(xy, c.index, centres, p.answer):
                fix = c.xy
        else:  # paper mode: the check, then the best answer
            usable &= credible(results, p.answer)
            if usable.any():
                k = int(np.argmax(np.where(usable, w, -1.0)))
                if supported(xy, k, centres, p.answer):
                    fix = xy[k]
        best = int(np.argmax(w))
        err = float(np.hypot(*(xy[best] - truth_en))) if finite[best] else math.inf
        null = results[best].null_w if results[best] is not None else None
        accepted = bool(np.isfinite(fix).all())
        return TriggerOutcome(err, float(w[best]), null, accepted,
                              float(np.hypot(*(fix - truth_en))) if accepted else math.nan)


@dataclass(frozen=True)
class _Place:
    name: str
    aerial: np.ndarray
    m_per_px: float
    truth_px: tuple[float, float]
    views: list[View]


def _utm_of_px(px: tuple[float, float], m_per_px: float) -> np.ndarray:
    return np.array([WEST + px[0] * m_per_px, NORTH - px[1] * m_per_px])


def _score_places(places: list[_Place], asker: _Asker, rng: np.random.Generator, tmp: Path) -> list[Try]:
    """Every view of every place against its own aerial and against the next place's (the wrong map)."""
    tifs = []
    for k, pl in enumerate(places):
        tif = tmp / f"aerial_{k}.tif"
        write_geotiff(tif, pl.aerial, WEST, NORTH, pl.m_per_px)
        tifs.append(tif)
    tries = []
    for k, pl in enumerate(places):
        other = (k + 1) % len(places)
        with SatelliteMap(tifs[k]) as own, SatelliteMap(tifs[other]) as wrong:
            truth = _utm_of_px(pl.truth_px, pl.m_per_px)
            wrong_truth = _utm_of_px(places[other].truth_px, places[other].m_per_px)
            for view in pl.views:
                d = float(rng.uniform(*PRIOR_OFFSET_M))
                a = float(rng.uniform(-math.pi, math.pi))
                off = d * np.array([math.cos(a), math.sin(a)])
                theta = math.radians(90.0 - view.bearing_deg)
                heading = theta + math.radians(float(rng.uniform(-HEADING_NOISE_DEG, HEADING_NOISE_DEG)))
                mine = asker.ask(view, own, truth, truth + off, heading)
                theirs = asker.ask(view, wrong, wrong_truth, wrong_truth + off, heading)
                tries.append(Try(pl.name, view.name, d, mine, theirs))
                log.debug("%s %s: prior %.1f m, best %.1f m w %.2f (chance %s) fix %s; wrong map w %.2f fix %s",
                          pl.name, view.name, d, mine.error_m, mine.w, mine.null_w, mine.accepted, theirs.w,
                          theirs.accepted)
    return tries


def real_places(root: Path, rng: np.random.Generator, per_set: int | None = None
                ) -> Iterator[tuple[RealSet, _Place]]:
    """Every place (the first per_set of each set; None: all) of every set under root, with its views."""
    for rset in find_sets(root):
        for pair in rset.pairs[:per_set]:
            image = read_rgb(pair.ground)
            aerial = read_rgb(pair.aerial)
            yield rset, _Place(f"{rset.name}/{pair.id}", aerial, rset.m_per_px, pair.truth_px,
                               _views(rset, image, pair.heading_deg, rng))


def synthetic_places(seed: int, n: int = SYNTHETIC_PLACES) -> list[_Place]:
    """n places of a seeded textured mosaic made as the real ones are: a view rendered at a seeded pose per
    VIEW_BEARINGS_DEG x VIEW_FOVS_DEG (the camera 2.5 m up), the aerial a 256 px crop at the real set's scale."""
    from rasterio.transform import from_origin

    from taco_mav.datasets.synthetic.render import GroundRenderer

    rng = np.random.default_rng(seed)
    m0, size = 0.2, 2500
    mosaic = textured_mosaic(seed, size, m0)
    side = 256
    extent = side * SYNTHETIC_M_PER_PX
    places = []
    for k in range(n):
        # the camera at the aerial's centre, the aerial whole inside the mosaic
        cx, cy = (float(v) for v in rng.uniform(extent / m0, size - extent / m0, 2))
        scale = m0 / SYNTHETIC_M_PER_PX
        M = np.array([[1 / scale, 0.0, cx - side / 2 / scale], [0.0, 1 / scale, cy - side / 2 / scale]])
        aerial = cv2.warpAffine(mosaic, M, (side, side), flags=cv2.INTER_AREA | cv2.WARP_INVERSE_MAP)
        turn = float(rng.uniform(0.0, 90.0))
        views = []
        for fov in VIEW_FOVS_DEG:
            height = int(round(VIEW_WIDTH_PX * VIEW_ASPECT))
            f = 0.5 * VIEW_WIDTH_PX / math.tan(math.radians(fov) / 2.0)
            K = np.array([[f, 0.0, (VIEW_WIDTH_PX - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
            cam = GroundCamera(K, VIEW_WIDTH_PX, height, SYNTHETIC_CAMERA_HEIGHT_M, math.radians(VIEW_PITCH_DEG))
            renderer = GroundRenderer(mosaic, from_origin(0.0, 0.0, m0, m0), cam, max_range_m=80.0)
            for b in VIEW_BEARINGS_DEG:
                bearing = (b + turn) % 360.0
                E, N = cx * m0, -cy * m0  # the mosaic's top-left corner at (0, 0)
                img = renderer.render((E, N, math.radians(90.0 - bearing)))
                views.append(View(img, cam, bearing, f"b{bearing:.0f}_f{fov:.0f}"))
        places.append(_Place(f"synthetic/{k}", aerial, SYNTHETIC_M_PER_PX, (side / 2.0, side / 2.0), views))
    return places


def _auc(pos: np.ndarray, neg: np.ndarray) -> float | None:
    if pos.size == 0 or neg.size == 0:
        return None
    return float(np.mean(pos[:, None] > neg[None, :]) + 0.5 * np.mean(pos[:, None] == neg[None, :]))


def figures(tries: list[Try], prefix: str) -> dict[str, Any]:
    """The bench keys of a list of tries (module docstring), each key prefixed."""
    err = np.array([t.own.error_m for t in tries])
    acc = np.array([t.own.accepted for t in tries])
    fix_ok = np.array([t.own.fix_error_m < SUCCESS_M for t in tries])
    return {
        f"{prefix}_tries": len(tries),
        f"{prefix}_within_3m_share": float(np.mean(err < SUCCESS_M)),
        f"{prefix}_median_error_m": float(np.median(err)),
        f"{prefix}_median_prior_error_m": float(np.median([t.prior_error_m for t in tries])),
        f"{prefix}_accepted_share": float(acc.mean()),
        f"{prefix}_accepted_precision": float(fix_ok[acc].mean()) if acc.any() else None,
        f"{prefix}_wrong_map_accepted_share": float(np.mean([t.wrong.accepted for t in tries])),
        f"{prefix}_w_auc": _auc(np.array([t.own.w for t in tries]), np.array([t.wrong.w for t in tries])),
    }


def evaluate_real(root: Path, profile: Profile, seed: int = 0, places_per_set: int | None = None
                  ) -> tuple[list[Try], dict[str, Any]]:
    """Tries and keys (real_*) for every set under root (its first places_per_set places each; None: all)."""
    rng = np.random.default_rng(seed)
    asker = _Asker(profile)
    by_set: dict[str, list[_Place]] = {}
    for rset, place in real_places(root, rng, places_per_set):
        by_set.setdefault(rset.name, []).append(place)
    tries: list[Try] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, places in by_set.items():
            if len(places) < 2:
                raise DataError(f"{root}: set {name} has one place; the wrong-map control needs two")
            tries += _score_places(places, asker, rng, Path(tmp))
    keys = figures(tries, "real")
    keys.update(real_sets=len(by_set), real_places=sum(len(v) for v in by_set.values()))
    return tries, keys


def evaluate_synthetic(profile: Profile, seed: int = 11, places: int = SYNTHETIC_PLACES
                       ) -> tuple[list[Try], dict[str, Any]]:
    """Tries and keys (synthetic_pairs_*) on synthetic places made as the real ones are."""
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        tries = _score_places(synthetic_places(seed, places), _Asker(profile), rng, Path(tmp))
    return tries, figures(tries, "synthetic_pairs")


def run(progress: bool = False, real_pairs: str | Path | None = None, profile: str = DEFAULT_PROFILE
        ) -> dict[str, Any]:
    """Bench entry point (see `taco_mav.bench`). Without `real_pairs` and with no set at the default place (a
    clone without ../shared), the real_* keys are absent and a warning says so; a folder given that holds no set
    is a DataError."""
    cv2.setNumThreads(1)
    prof = load_profile(profile)
    keys: dict[str, Any] = {"real_profile": prof.name}
    root = Path(real_pairs) if real_pairs else default_root()
    if real_pairs or root.is_dir():
        keys.update(evaluate_real(root, prof)[1])
    else:
        log.warning("bench real: no real pairs at %s (give --real-pairs DIR or TACO_REAL_PAIRS): the real_* keys "
                    "are absent", root)
    keys.update(evaluate_synthetic(prof)[1])
    return keys
