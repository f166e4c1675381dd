"""Answer a Localiser FixQuery: cut the crops from the satellite map, run the matcher, keep the crop order.

Used by both the offline evaluator and the live daemon, so that the matcher sees the same crops either way.
Query positions are ENU metres relative to the origin; the map wants absolute UTM, so `origin_utm` is added.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

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


class FixService:
    """matcher: any `Matcher`; sat_map: the mosaic, or None for matchers that need no imagery (the emulator on
    image-less drives: crops then carry an empty image but the right centre and heading); origin_utm: (2,)
    UTM easting/northing of the Localiser's origin; crop_size_px and m_per_px from the profile's `map`."""

    def __init__(self, matcher: Matcher, sat_map: SatelliteMap | None, origin_utm: np.ndarray, crop_size_px: int = 512,
                 m_per_px: float = 0.2) -> None:
        self.matcher = matcher
        self.map = sat_map
        self.origin = np.asarray(origin_utm, dtype=float)
        self.size = int(crop_size_px)
        self.m_per_px = float(m_per_px)
        self.stats = ServiceStats()

    def crops(self, query: FixQuery) -> list[Crop | None]:
        """The query's crops in order; None where a crop is off the map."""
        out: list[Crop | None] = []
        for c in query.crop_centres:
            centre = self.origin + np.asarray(c, dtype=float)
            if self.map is None:
                out.append(Crop(np.zeros((0, 0, 3), np.uint8), centre, float(query.heading), self.m_per_px))
                continue
            try:
                out.append(self.map.crop(centre, query.heading, self.size, self.m_per_px))
            except OffMapError as exc:
                self.stats.crops_off_map += 1
                log.debug("query %d: %s", query.query_id, exc)
                out.append(None)
        return out

    def _cut_on_device(self, query: FixQuery) -> Any:
        """The query's crops cut by the matcher on its device (DeviceCrops: off-map ones flagged and counted)."""
        centres = self.origin + np.asarray(query.crop_centres, dtype=float).reshape(-1, 2)
        matcher: Any = self.matcher  # a GeometryMatcher (checked by uses_device_crops)
        batch = matcher.cut_crops(self.map, centres, query.heading, self.size, self.m_per_px)
        for exc in batch.errors:
            if exc is not None:
                self.stats.crops_off_map += 1
                log.debug("query %d: %s", query.query_id, exc)
        return batch

    def answer(self, query: FixQuery, frame: GroundFrame) -> list[MatchResult | None]:
        """MatchResults aligned with query.crop_centres (None for crops off the map). ValueError when the
        matcher's answer is malformed (wrong count, type or shape)."""
        t0 = time.perf_counter()
        if self.map is not None and uses_device_crops(self.matcher):  # fg2.device_crops: the matcher warps them
            batch = self._cut_on_device(query)
            present = list(batch.present)
            t1 = time.perf_counter()
            n = sum(present)
            matcher: Any = self.matcher
            results = _check_results(matcher.match_crops(frame, batch), n) if n else []
        else:
            crops = self.crops(query)
            present = [c is not None for c in crops]
            t1 = time.perf_counter()
            valid = [c for c in crops if c is not None]
            results = _check_results(self.matcher.match(frame, valid), len(valid)) if valid else []
        t2 = time.perf_counter()
        if not any(present):
            self.stats.triggers_off_map += 1
        it = iter(results)
        aligned = [next(it) if p else None for p in present]
        self.stats.answered += 1
        self.stats.crop_s += t1 - t0
        self.stats.matcher_s += t2 - t1
        self.stats.per_trigger_s.append(t2 - t0)
        return aligned
