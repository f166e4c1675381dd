"""Shadow mode (`taco-mav run --shadow`): how far off would taco_mav be without GNSS, measured while
a real receiver is still honest.

A twin of the Localiser runs beside the one whose estimate goes to the autopilot: made with it at every
(re-)anchoring (`LocaliserAnchor.twin`), fed the same IMU samples, drive commands, camera fixes (the main filter's
queries, `Localiser.adopt_query`, answered by the same matcher call) and camera ground motion, but never GNSS.
While the receiver is honest (the GNSS tracker's state "ok", no spoofing rejection), once a second of autopilot
time the twin's distance to the receiver's latest fix (carried to the twin's time at the fix's velocity) goes to the
ground station as NAMED_VALUE_FLOAT `taco_shad` (m) and to events.jsonl as `shadow` (t autopilot s, lat, lon of
the twin, its h_acc_m, gnss_err_m); the session's last line says how it went (`summary`).

The twin's camera answers also qualify the area (`taco_mav.daemon.survey`): each answer, accepted or not, is
compared with the honest receiver at its frame's capture time (carried there at the fix's velocity, up to
SURVEY_CARRY_S), and the session ends with a verdict for the whole drive and per stretch driven: "camera fixes
usable here / not usable here" (`summary()["survey"]`, the `line()` and the `stop` event).

The output always comes from the fused filter, so when the receiver goes nothing the autopilot sees jumps: the
twin only measures. It costs a second filter's IMU work (measured in `taco-mav bench`, daemon keys).

Frames and units: ENU metres from the origin; times autopilot seconds; lat, lon degrees WGS84.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any
import numpy as np

from taco_mav.core.frames import FixOutcome
from taco_mav.core.localiser import Localiser
from taco_mav.core.types import GnssFix, MatchResult
from taco_mav.daemon.survey import SurveyAnswer, stretches, verdict
from taco_mav.mavlink import encoders

log = logging.getLogger(__name__)

__all__ = ["SHADOW_NAME", "Shadow", "twin_fix"]

SHADOW_NAME = "taco_shad"  # NAMED_VALUE_FLOAT name (10 characters at most)
SHADOW_HZ = 1.0  # reports per second of autopilot time
MAX_CARRY_S = 1.0  # a fix older than this (autopilot s) next to the twin's time is not compared
SURVEY_CARRY_S = 3.0  # a camera answer is compared with a receiver fix at most this far (autopilot s) from it


class Shadow:
    """The GNSS-free twin and what it measured (errors: gnss_err_m of each 1 Hz report)."""

    def __init__(self) -> None:
        self.twin: Localiser | None = None
        self.errors: list[float] = []
        self._next_t = -float("inf")  # autopilot s of the next report
        self.answers: list[SurveyAnswer] = []  # the twin's camera answers, compared with the receiver
        self._pending: list[FixOutcome] = []  # answers waiting for a receiver fix near their capture time
        self._odo = 0.0  # metres the twin has driven (its estimate, sampled at each report)
        self._last_xy: np.ndarray | None = None

    def due(self) -> bool:
        """True once per second of autopilot time (the twin's clock) while a twin runs."""
        if self.twin is None or self.twin.t < self._next_t:
            return False
        self._next_t = self.twin.t + 1.0 / SHADOW_HZ
        return True

    def anchored(self, twin: Localiser) -> None:
        """The main Localiser was (re-)anchored: `twin` starts beside it, from the same state."""
        self.twin = twin

    def compare(self, fix: GnssFix | None, origin: encoders.Origin | None) -> dict[str, float] | None:
        """The twin against an honest receiver's latest fix (None: no honest fix now) in the origin's frame: the
        `shadow` event's fields, or None when there is nothing to compare (no twin, fix or origin yet, the fix too
        far from the twin's time)."""
        twin = self.twin
        if twin is None:
            return None
        est = twin.estimate()
        if np.all(np.isfinite(est.xy)):
            if self._last_xy is not None:
                self._odo += float(np.hypot(*(np.asarray(est.xy) - self._last_xy)))
            self._last_xy = np.asarray(est.xy, dtype=float)
        self._survey(fix, est.t)
        if fix is None or origin is None:
            return None
        dt = est.t - fix.t
        if abs(dt) > MAX_CARRY_S or not np.all(np.isfinite(est.xy)):
            return None
        at = fix.xy + (fix.vel_en * dt if fix.vel_en is not None else 0.0)
        err = float(np.hypot(*(np.asarray(est.xy) - at)))
        lat, lon = origin.latlon(np.asarray(est.xy))
        self.errors.append(err)
        return {"t": float(est.t), "lat": float(lat), "lon": float(lon), "h_acc_m": float(est.sigma_h),
                "gnss_err_m": err}

    def answered(self, out: FixOutcome) -> None:
        """The twin's outcome of one camera answer: judged against the receiver once one is near its capture."""
        self._pending.append(out)

    def _survey(self, fix: GnssFix | None, t: float) -> None:
        """Compare the pending answers with `fix` (an honest receiver's latest, or None) where it is near their
        capture; those left SURVEY_CARRY_S behind the twin's time `t` without one count with no comparison."""
        keep = []
        for out in self._pending:
            err = float("nan")
            if fix is not None and abs(out.capture_t - fix.t) <= SURVEY_CARRY_S:
                if out.xy is not None and np.all(np.isfinite(out.xy)):
                    at = fix.xy + (fix.vel_en * (out.capture_t - fix.t) if fix.vel_en is not None else 0.0)
                    err = float(np.hypot(*(np.asarray(out.xy) - at)))
            elif t - out.capture_t <= SURVEY_CARRY_S:
                keep.append(out)
                continue
            self.answers.append(SurveyAnswer(out.capture_t, self._odo, out.accepted, err))
        self._pending = keep

    def summary(self) -> dict[str, Any]:
        """Reports, and the median / 95th percentile / largest of the twin's distance to the receiver, m; the
        survey of the camera's answers (whole drive and per stretch)."""
        e = np.array(self.errors)
        survey = {"drive": verdict(self.answers).as_dict(),
                  "stretches": [v.as_dict() for v in stretches(self.answers)]}
        if not len(e):
            return {"reports": 0, "survey": survey}
        return {"reports": len(e), "gnss_err_median_m": float(np.median(e)),
                "gnss_err_p95_m": float(np.percentile(e, 95)), "gnss_err_max_m": float(e.max()), "survey": survey}

    def line(self) -> str:
        """The session's summary line: the twin's distance to the receiver, then the survey's verdict."""
        s = self.summary()
        survey = verdict(self.answers).line()
        if not s["reports"]:
            return f"shadow: no comparison (no honest GNSS while the twin ran); {survey}"
        return (f"shadow: without GNSS taco_mav would have been {s['gnss_err_median_m']:.2f} m from the receiver "
                f"(median of {s['reports']} 1 Hz reports; 95 % within {s['gnss_err_p95_m']:.2f} m, largest "
                f"{s['gnss_err_max_m']:.2f} m); {survey}")


def twin_fix(twin: Localiser, query_id: int, results: Sequence[MatchResult | None], shadow: Shadow | None = None
             ) -> str:
    """The main filter's camera answer to the twin (its own gates decide; the outcome goes to `shadow`'s survey);
    returns the outcome's reason. The twin only measures, so an error in it is logged and never stops the loop."""
    try:
        out = twin.add_fix(query_id, results)
    except Exception:  # noqa: BLE001
        log.exception("shadow twin: add_fix failed on query %d", query_id)
        twin.cancel_query(query_id)
        return "error"
    if shadow is not None:
        shadow.answered(out)
    return out.reason
