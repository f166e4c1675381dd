"""Whether a matcher's answer says more than chance: the check that stands where no gate against the track does.

A matcher's weight w is its confidence that the answer is right, but on a scene it cannot read its best wrong
answer can carry as high a w as a right one: on real Street View beside satellite imagery the classical matcher's
w was as high for answers 20-40 m off as the highest it gave (docs/matchers.md), and FG2's silent outliers carry
ordinary weights too. So each trigger also asks the matcher for decoys (`taco_mav.cvgl.service.FixService`): the
trigger's centre crop turned by a quarter, three quarters and half a turn, a heading known wrong. What the matcher
scores there with a yaw residual within the gate (an answer that takes the wrong heading as right) is this scene's
chance level, and it travels with each answer as `MatchResult.null_w`. A matcher that recovers the turn (|psi|
beyond the gate) has recognised the place, and a decoy that lands where the answer does has found the same ground
turned (a crossing looks alike a quarter turn round): neither is evidence of chance and neither counts.

An answer is credible when it is usable (finite, w >= w_min) and, where the trigger had decoys, its log-odds
log(w / (1 - w)) exceed the chance level's by at least `decoy_margin`; it is supported when, of the trigger's
crops that could give it (centre within `agree_window_m`), at least `min_agree_share` and at least two place the
camera within `agree_radius_m` of it. Agreement alone is no evidence (a chance peak lies inside every crop's
search window, and the five crops often find it within 0.02 m of each other), nor is beating the decoys alone
(the best of five crops against the best of three decoys: three real answers 28-46 m off did, each given by one
crop); both together refused every answer on the real pairs and kept every right one on the synthetic pairs.

Where it applies: paper mode, which has no gate of its own, and taco+ while lock is lost, when nothing but this
stands between an answer and a relocalisation (without it, a 3-D world driven through buildings relocalises by
22 and 34 m on such answers: docs/matchers.md). While locked, taco+'s innovation gate against the track decides:
on SITL's 3-D world its right answers have w 0.2-0.5 beside decoys at 0.7-0.99 (the synthetic streets repeat),
which the decoy test would refuse.

Weights in [0, 1]; positions metres; pure maths, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from taco_mav.core.params import AnswerParams
from taco_mav.core.types import MatchResult

__all__ = ["credible", "log_odds", "supported"]

_W_CLIP = 1e-12  # log-odds of w in [1e-12, 1 - 1e-12]: +-27.6


def log_odds(w: float) -> float:
    """log(w / (1 - w)) with w clipped into (0, 1)."""
    w = min(max(float(w), _W_CLIP), 1.0 - _W_CLIP)
    return math.log(w / (1.0 - w))


def credible(results: Sequence[MatchResult | None], p: AnswerParams) -> np.ndarray:
    """Per answer (K,) bool: finite, w >= p.w_min and, when the answer carries a chance level (null_w), its
    log-odds at least p.decoy_margin above it. None (a crop off the map) is never credible."""
    out = np.zeros(len(results), dtype=bool)
    for k, r in enumerate(results):
        if r is None or not math.isfinite(r.w) or r.w <= 0.0 or r.w < p.w_min:
            continue
        if r.null_w is not None and math.isfinite(r.null_w) and p.decoy_margin > 0.0:
            if log_odds(r.w) - log_odds(r.null_w) < p.decoy_margin:
                continue
        out[k] = True
    return out


def supported(xy: np.ndarray, index: int, centres: np.ndarray, p: AnswerParams) -> bool:
    """Whether the chosen answer `index` is supported: of the answered crops whose centre (centres (K, 2), m) lies
    within p.agree_window_m of it, at least p.min_agree_share, and at least two, place the camera (xy (K, 2), m;
    nan where a crop has no answer) within p.agree_radius_m of it. A single-crop trigger supports itself."""
    if p.min_agree_share <= 0.0:
        return True
    pts = np.asarray(xy, float).reshape(-1, 2)
    answered = np.isfinite(pts).all(axis=1)
    if int(answered.sum()) <= 1:
        return bool(answered[index])
    c = np.asarray(centres, float).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        seeing = answered & (np.linalg.norm(c - pts[index], axis=1) <= p.agree_window_m)
        near = np.linalg.norm(pts - pts[index], axis=1) <= p.agree_radius_m
    need = max(2, math.ceil(p.min_agree_share * int(seeing.sum()) - 1e-9))
    return int(np.sum(near & seeing)) >= need
