"""Answer a Localiser FixQuery: cut the crops from the satellite map, run the matcher, keep the crop order.

Used by both the offline evaluator and the live daemon, so that the matcher sees the same crops either way.
Query positions are ENU metres relative to the origin; the map wants absolute UTM, so `origin_utm` is added.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from taco_mav.config import Profile
from taco_mav.core.gate import yaw_residual
from taco_mav.core.search import fix_position
from taco_mav.core.types import FixQuery, MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame, Matcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.errors import OffMapError

log = logging.getLogger(__name__)


@dataclass
class ServiceStats:
    """Counters: triggers answered, crops off the map, triggers with every crop off the map, matcher and crop
    wall time (s); per_trigger_s: the last 10 000 triggers' wall times, s (bounded for long runs)."""

    answered: int = 0
    crops_off_map: int = 0
    triggers_off_map: int = 0
    matcher_s: float = 0.0
    crop_s: float = 0.0
    per_trigger_s: deque[float] = field(default_factory=lambda: deque(maxlen=10_000))


def _check_results(results: object, n: int) -> list[MatchResult]:
    """The matcher's answer for n crops, or ValueError naming what is wrong (count, type or shape)."""
    if not isinstance(results, (list, tuple)) or len(results) != n:
        got = len(results) if isinstance(results, (list, tuple)) else type(results).__name__
        raise ValueError(f"matcher returned {got} results for {n} crops")
    for r in results:
        if not isinstance(r, MatchResult) or np.shape(r.R) != (2, 2) or np.shape(r.t) != (2,):
            raise ValueError(f"matcher returned a malformed result: {r!r:.120}")
    return list(results)


def uses_device_crops(matcher: object) -> bool:
    """The matcher cuts its own crops on its device (taco_mav.cvgl.fg2.device_crops.GeometryMatcher, switched on by
    fg2.device_crops); checked by attribute so that torch is not imported here."""
    return (bool(getattr(matcher, "device_crops", False)) and callable(getattr(matcher, "cut_crops", None))
            and callable(getattr(matcher, "match_crops", None)))


DECOY_TURNS_RAD = (0.5 * math.pi, -0.5 * math.pi, math.pi)  # decoy k turns the centre crop by the k-th of these


def chance_levels(own: Sequence[MatchResult | None], own_xy: np.ndarray, decoys: Sequence[MatchResult | None],
                  decoy_xy: np.ndarray, yaw_gate_rad: float | None, apart_m: float) -> list[float | None]:
    """Each own answer's chance level: the highest w among decoy answers that take the decoy's (wrong) heading as
    right (|psi| within the yaw gate; None: every answer) and place the camera more than `apart_m` from that answer
    (a decoy that lands on the answer has found the same place turned: symmetric ground, a crossing, not chance).
    own_xy (K, 2) / decoy_xy (D, 2): where each answer puts the camera, m in one frame. 0.0 when no decoy counts;
    None for a crop without an answer."""
    out: list[float | None] = []
    for r, xy in zip(own, own_xy):
        if r is None:
            out.append(None)
            continue
        level = 0.0
        for d, dxy in zip(decoys, decoy_xy):
            if d is None or not math.isfinite(d.w):
                continue
            if yaw_gate_rad is not None and abs(yaw_residual(d.R)) > yaw_gate_rad:
                continue
            if np.all(np.isfinite(xy)) and np.all(np.isfinite(dxy)) and float(np.hypot(*(dxy - xy))) <= apart_m:
                continue
            level = max(level, float(d.w))
        out.append(level)
    return out


class FixService:
    """matcher: any `Matcher`; sat_map: the mosaic, or None for matchers that need no imagery (the emulator on
    image-less drives: crops then carry an empty image but the right centre and heading); origin_utm: (2,)
    UTM easting/northing of the Localiser's origin; crop_size_px and m_per_px from the profile's `map`; decoys:
    crops turned to a heading known wrong asked beside each trigger (profile answer.decoys, 0-3; their in-gate
    answers away from an answer set its `null_w`, core/answer_check.py), yaw_gate_rad the gate that tells an
    in-gate answer (profile gate.yaw_residual_max_rad; None: the gate is off), decoy_apart_m how far from an answer
    a decoy's must land to count (profile answer.agree_radius_m)."""

    def __init__(self, matcher: Matcher, sat_map: SatelliteMap | None, origin_utm: np.ndarray, crop_size_px: int = 512,
                 m_per_px: float = 0.2, *, decoys: int = 0, yaw_gate_rad: float | None = None,
                 decoy_apart_m: float = 3.0) -> None:
        if not 0 <= decoys <= len(DECOY_TURNS_RAD):
            raise ValueError(f"decoys {decoys}: 0 to {len(DECOY_TURNS_RAD)}")
        self.matcher = matcher
        self.map = sat_map
        self.origin = np.asarray(origin_utm, dtype=float)
        self.size = int(crop_size_px)
        self.m_per_px = float(m_per_px)
        self.decoy_turns = DECOY_TURNS_RAD[:decoys] if sat_map is not None else ()
        self.yaw_gate_rad = yaw_gate_rad
        self.decoy_apart_m = float(decoy_apart_m)
        self.stats = ServiceStats()

    def crops(self, query: FixQuery, n_own: int | None = None) -> list[Crop | None]:
        """The query's crops in order; None where a crop is off the map. Crops past the first n_own (default:
        all are the query's own) are decoys, turned by DECOY_TURNS_RAD in order."""
        out: list[Crop | None] = []
        n_own = len(query.crop_centres) if n_own is None else n_own
        for k, c in enumerate(query.crop_centres):
            centre = self.origin + np.asarray(c, dtype=float)
            heading = float(query.heading) + (self.decoy_turns[k - n_own] if k >= n_own else 0.0)
            if self.map is None:
                out.append(Crop(np.zeros((0, 0, 3), np.uint8), centre, heading, self.m_per_px))
                continue
            try:
                out.append(self.map.crop(centre, heading, self.size, self.m_per_px))
            except OffMapError as exc:
                self.stats.crops_off_map += 1
                log.debug("query %d: %s", query.query_id, exc)
                out.append(None)
        return out

    def _cut_on_device(self, query: FixQuery, heading: float) -> Any:
        """The query's crops cut at `heading` (ENU rad) by the matcher on its device (DeviceCrops: off-map ones
        flagged and counted)."""
        centres = self.origin + np.asarray(query.crop_centres, dtype=float).reshape(-1, 2)
        matcher: Any = self.matcher  # a GeometryMatcher (checked by uses_device_crops)
        batch = matcher.cut_crops(self.map, centres, heading, self.size, self.m_per_px)
        for exc in batch.errors:
            if exc is not None:
                self.stats.crops_off_map += 1
                log.debug("query %d: %s", query.query_id, exc)
        return batch

    def answer(self, query: FixQuery, frame: GroundFrame) -> list[MatchResult | None]:
        """MatchResults aligned with query.crop_centres (None for crops off the map), each with the trigger's
        chance level (`null_w`) when the service asks decoys. ValueError when the matcher's answer is malformed
        (wrong count, type or shape)."""
        t0 = time.perf_counter()
        n_own = len(query.crop_centres)
        decoy_q = query
        if self.decoy_turns:  # the decoys ride in the same matcher call, after the trigger's own crops
            own_centres = np.asarray(query.crop_centres, dtype=float).reshape(-1, 2)
            decoy_centres = np.repeat(own_centres.mean(axis=0)[None, :], len(self.decoy_turns), axis=0)
            decoy_q = dataclasses.replace(query, crop_centres=np.vstack([own_centres, decoy_centres]))
        if self.map is not None and uses_device_crops(self.matcher):  # fg2.device_crops: the matcher warps them
            present, results, t1 = self._on_device(decoy_q, frame, n_own)
        else:
            crops = self.crops(decoy_q, n_own)
            present = [c is not None for c in crops]
            t1 = time.perf_counter()
            valid = [c for c in crops if c is not None]
            results = _check_results(self.matcher.match(frame, valid), len(valid)) if valid else []
        t2 = time.perf_counter()
        it = iter(results)
        aligned = [next(it) if p else None for p in present]
        own, decoys = aligned[:n_own], aligned[n_own:]
        if self.decoy_turns:
            centres = np.asarray(decoy_q.crop_centres, dtype=float).reshape(-1, 2)
            headings = [float(query.heading)] * n_own + [float(query.heading) + t for t in self.decoy_turns]
            xy = np.array([fix_position(c, h, r.t) if r is not None else (np.nan, np.nan)
                           for c, h, r in zip(centres, headings, aligned)]).reshape(-1, 2)
            levels = chance_levels(own, xy[:n_own], decoys, xy[n_own:], self.yaw_gate_rad, self.decoy_apart_m)
            own = [dataclasses.replace(r, null_w=lv) if r is not None else None for r, lv in zip(own, levels)]
        if not any(present[:n_own]):
            self.stats.triggers_off_map += 1
        self.stats.answered += 1
        self.stats.crop_s += t1 - t0
        self.stats.matcher_s += t2 - t1
        self.stats.per_trigger_s.append(t2 - t0)
        return own

    def _on_device(self, query: FixQuery, frame: GroundFrame, n_own: int) -> tuple[list[bool], list[MatchResult],
                                                                                 float]:
        """(present, results of the present crops, time the crops were cut) on the matcher's device: the trigger's
        crops at the query heading, then each decoy at its own turn."""
        centres = np.asarray(query.crop_centres, dtype=float).reshape(-1, 2)
        batches = [self._cut_on_device(dataclasses.replace(query, crop_centres=centres[:n_own]), query.heading)]
        for k, turn in enumerate(self.decoy_turns):
            one = dataclasses.replace(query, crop_centres=centres[n_own + k:n_own + k + 1])
            batches.append(self._cut_on_device(one, query.heading + turn))
        t1 = time.perf_counter()
        matcher: Any = self.matcher
        present: list[bool] = []
        results: list[MatchResult] = []
        for batch in batches:
            flags = list(batch.present)
            n = sum(flags)
            present += flags
            results += _check_results(matcher.match_crops(frame, batch), n) if n else []
        return present, results, t1


def profile_service(matcher: Matcher, sat_map: SatelliteMap | None, origin_utm: np.ndarray, profile: Profile
                    ) -> FixService:
    """The FixService a profile asks for: its map's crop size and scale, its answer check's decoys and yaw gate.
    The evaluator, the daemon and the real-imagery bench all build it here."""
    return FixService(matcher, sat_map, origin_utm, profile.map.crop_size_px, profile.map.crop_m_per_px,
                      decoys=profile.answer.decoys,
                      yaw_gate_rad=profile.gate.yaw_residual_max_rad if profile.gate.enabled else None,
                      decoy_apart_m=profile.answer.agree_radius_m)
