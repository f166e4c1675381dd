"""Ground-station health: what the localiser is doing, as NAMED_VALUE_FLOAT once a second (autopilot time) and
a STATUSTEXT whenever its mode changes. ArduPilot forwards both from the companion to every ground station
link, so MAVProxy and Mission Planner show them (docs/ardupilot.md, "Ground-station health").

Values (names are at most 10 characters, the field's size):
- taco_mode: `TacoMode` code (below); taco_gnss: `GNSS_CODES` code of the real receiver;
- taco_hacc: horizontal 1-sigma accuracy sent in the last position output, m (sent once an estimate exists);
- taco_age: seconds (autopilot) since the last accepted camera fix (or since the estimator started);
- taco_w: the best crop's match weight w in (0, 1] of the last answered camera query, 0 before any;
- taco_cam: the share of the last answered camera queries that made a fix, taco_chnc: the share that said nothing
  (`MatcherHealth`, daemon/matcher_health.py), both once the estimator runs.

Camera at chance: `MatcherHealth` says so (no fix among the last answered queries, most of them no better than
chance); over at the next accepted fix.

Camera lost: queries have failed for want of a usable frame (no, stale, corrupt, blank, frozen or mis-sized
frames) and no frame has reached the matcher for `camera_lost_s`; over as soon as one does. Off map: the last
answered queries had every crop outside the satellite map; over when one had a crop on it.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass

from taco_mav.core.types import Estimate
from taco_mav.daemon.matcher_health import MatcherHealth
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_NOTICE, SEV_WARNING

__all__ = ["CAMERA_FAULTS", "GCS_HEALTH_HZ", "GNSS_CODES", "GcsHealth", "GcsReport", "TacoMode"]

GCS_HEALTH_HZ = 1.0  # NAMED_VALUE_FLOAT rate, Hz of autopilot time
CAMERA_LOST_S = 3.0  # s (companion) of camera faults without a frame reaching the matcher: camera lost
CAMERA_FAULTS = frozenset({"no_frame", "stale_frame", "corrupt_frame", "bad_shape", "blank_frame", "frozen_frame"})
GNSS_CODES = {"none": 0, "ok": 1, "lost": 2, "rejected": 3}  # never had a 3D fix / fused / lost / refused (spoofed?)


class TacoMode(enum.IntEnum):
    """taco_mode codes. Once the estimator runs, the first that applies of CAMERA_LOST, OFF_MAP, AT_CHANCE,
    RELOCALISING, CONFIRMING, DEGRADED, else TRACKING."""

    STARTING = 0  # no origin or no estimator yet: nothing is sent to the autopilot
    TRACKING = 1  # output healthy (3D fix); taco+: lock held
    CONFIRMING = 2  # taco+: relocalised, confirming the jump with further fixes
    RELOCALISING = 3  # taco+: lock lost, searching a wider area
    CAMERA_LOST = 4  # no usable camera frames (see the module docstring)
    OFF_MAP = 5  # the search area is outside the satellite map
    DEGRADED = 6  # output degraded to no fix: accuracy above output.degrade_accuracy_m, or the IMU stalled
    AT_CHANCE = 7  # the camera's answers are no better than chance here (daemon/matcher_health.py): none fused


_SEVERITY = {TacoMode.STARTING: SEV_INFO, TacoMode.TRACKING: SEV_INFO, TacoMode.CONFIRMING: SEV_NOTICE}


@dataclass(frozen=True)
class GcsReport:
    """values: (name, value) pairs to send as NAMED_VALUE_FLOAT; change: (severity, text) for a STATUSTEXT when
    the mode changed, else None."""

    values: list[tuple[str, float]]
    change: tuple[int, str] | None


class GcsHealth:
    """The mode state machine and the values; `update` once a second."""

    def __init__(self, camera_lost_s: float = CAMERA_LOST_S) -> None:
        self.camera_lost_s = camera_lost_s
        self.mode = TacoMode.STARTING
        self.changes = 0
        self.camera_lost = False
        self.off_map = False
        self._answered = 0
        self._off_map_triggers = 0
        self._faults = 0
        self._frame_at: float | None = None
        self.matcher = MatcherHealth()

    def _camera(self, now: float, fixes: Mapping[str, int], answered: int, off_map_triggers: int) -> None:
        faults = sum(n for k, n in fixes.items() if k in CAMERA_FAULTS)
        d_ans, d_off, d_faults = answered - self._answered, off_map_triggers - self._off_map_triggers, faults - self._faults
        self._answered, self._off_map_triggers, self._faults = answered, off_map_triggers, faults
        if self._frame_at is None:
            self._frame_at = now
        if d_ans > 0:
            self._frame_at, self.camera_lost = now, False
        elif d_faults > 0 and now - self._frame_at >= self.camera_lost_s:
            self.camera_lost = True
        if d_ans > d_off:
            self.off_map = False
        elif d_off > 0:
            self.off_map = True

    def update(self, now: float, est: Estimate | None, hacc_m: float | None, healthy: bool, gnss: str,
               fixes: Mapping[str, int], answered: int, off_map_triggers: int, weight: float) -> GcsReport:
        """now: companion s; est: the Localiser's estimate (None before it runs); hacc_m: the accuracy of the last
        position output, m (None: none sent yet); healthy: that output was a 3D fix; gnss: a GNSS_CODES key;
        fixes: fix outcome counters by reason; answered / off_map_triggers: the FixService's answered queries
        and those with every crop off the map; weight: the last answered query's best w."""
        self._camera(now, fixes, answered, off_map_triggers)
        self.matcher.count(fixes)
        lock = est.extra.get("lock") if est is not None else None
        if est is None:
            mode = TacoMode.STARTING
        elif self.camera_lost:
            mode = TacoMode.CAMERA_LOST
        elif self.off_map:
            mode = TacoMode.OFF_MAP
        elif self.matcher.verdict == "at_chance":
            mode = TacoMode.AT_CHANCE
        elif lock == "lost":
            mode = TacoMode.RELOCALISING
        elif lock == "confirming":
            mode = TacoMode.CONFIRMING
        elif not healthy:
            mode = TacoMode.DEGRADED
        else:
            mode = TacoMode.TRACKING
        change = None
        if mode is not self.mode:
            text = self.matcher.describe() if mode is TacoMode.AT_CHANCE else f"mode {mode.name} (was {self.mode.name})"
            change = (_SEVERITY.get(mode, SEV_WARNING), text)
            self.mode = mode
            self.changes += 1
        values = [("taco_mode", float(mode)), ("taco_gnss", float(GNSS_CODES.get(gnss, 0)))]
        if est is not None:
            age = est.since_fix_s if math.isfinite(est.since_fix_s) else -1.0
            hacc = hacc_m if hacc_m is not None and math.isfinite(hacc_m) else 1000.0
            values += [("taco_hacc", min(hacc, 1000.0)), ("taco_age", max(age, -1.0)),
                       ("taco_w", weight if math.isfinite(weight) else 0.0),
                       ("taco_cam", self.matcher.accepted_share), ("taco_chnc", self.matcher.chance)]
        return GcsReport(values, change)
