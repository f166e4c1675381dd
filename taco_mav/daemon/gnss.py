"""Real GNSS on the autopilot's side: which GPS instance is a real receiver, its readings as
`GnssFix` measurements for the Localiser, and the events a hand-over produces. Pure bookkeeping and
conversion (no sockets); the daemon feeds it messages and writes what it returns.

Instances: GPS_RAW_INT reports GPS1 (instance 1), GPS2_RAW GPS2 (instance 2), as ArduPilot sends them (PX4:
its first and second receiver, `sensor_gps` 0 and 1). Our GPS_INPUT (PX4: HIL_GPS) goes to instance
`gps_id + 1`; when its GPSn_TYPE is 14 (MAV) that instance only echoes what we send,
so it is never read as GNSS. Until the parameter answer is known it is taken to be ours; another instance of
type 14 is fed by someone else's GPS_INPUT and is not a receiver either; type 0 is no GPS.

State (companion clock, s): "none" until the first usable 3D fix; "ok"; "lost" when no usable 3D fix came for
`lost_after_s` (silence or fix type below 3D); back to "ok" once 3D fixes have run for `back_after_s` without
a NO_FIX in between. The spoofing guard itself is the Localiser's (`add_gnss` -> `GnssOutcome`): here the first
rejection of a run becomes `gnss_rejected`, the next use `gnss_accepted_again`.

Frames and units: GnssFix.xy ENU metres from the origin on its UTM grid; vel_en grid east/north m/s (course
over ground is true: grid angle = true angle + meridian convergence); accuracies 1-sigma metres and m/s.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from taco_mav.core.types import GnssFix, GnssOutcome
from taco_mav.mavlink.decoders import AutopilotPosition, GnssReading
from taco_mav.mavlink.encoders import Origin
from taco_mav.mavlink.mavconst import GPS_TYPE_MAV, GPS_TYPE_NONE, SEV_NOTICE, SEV_WARNING

log = logging.getLogger(__name__)

__all__ = ["GnssEvent", "GnssTracker", "distance_m", "gnss_fix", "moved_from_origin", "sigma_h_of", "SEV_WARNING",
           "SEV_NOTICE"]

DEFAULT_SIGMA_V_MPS = 0.5  # speed 1-sigma when the receiver reports none
FALLBACK_SIGMA_H_M = 10.0  # position 1-sigma with neither h_acc nor HDOP
MAX_RANGE_M = 50_000.0  # a fix farther than this from the origin is not our vehicle's (counted, never used)
MAX_TIME_SKEW_S = 2.0  # a fix stamped further than this from the autopilot's now is stamped now
STEADY_FIXES = 2  # consecutive 3D fixes, each within STEADY_STEP_M of the last, before one may be the origin
STEADY_STEP_M = 50.0
M_PER_DEG = 111_320.0
START_NEAR_M = 5.0  # a first fix within max(this, 3 sigma) of an offered origin does not move the start


def moved_from_origin(f: GnssFix) -> bool:
    """True when a real fix is farther from the offered origin (EKF origin, home) than its accuracy explains
    (> max(START_NEAR_M, 3 sigma)): the vehicle is no longer there, so the first Localiser starts at the fix."""
    return float(np.hypot(*f.xy)) > max(START_NEAR_M, 3.0 * f.sigma_h_m)


def sigma_h_of(r: GnssReading, hdop_uere_m: float) -> float:
    """1-sigma horizontal accuracy, m: the receiver's h_acc, else HDOP x UERE, else FALLBACK_SIGMA_H_M."""
    if r.h_acc_m is not None and r.h_acc_m > 0:
        return float(r.h_acc_m)
    if r.hdop is not None and r.hdop > 0:
        return float(r.hdop * hdop_uere_m)
    return FALLBACK_SIGMA_H_M


def gnss_fix(r: GnssReading, origin: Origin, hdop_uere_m: float, t: float | None = None) -> GnssFix:
    """The reading as a Localiser measurement: ENU metres from `origin`, grid velocity (None when speed or
    course is unknown while moving), 1-sigma accuracies. t: autopilot s (default the reading's own stamp)."""
    xy = origin.xy(r.lat, r.lon)
    vel: np.ndarray | None = None
    if r.speed_known and r.course_ned is not None:
        angle = math.pi / 2.0 - r.course_ned + origin.convergence
        vel = r.speed * np.array([math.cos(angle), math.sin(angle)])
    elif r.speed_known and r.speed == 0.0:
        vel = np.zeros(2)
    sigma_v = r.vel_acc_mps if r.vel_acc_mps is not None and r.vel_acc_mps > 0 else DEFAULT_SIGMA_V_MPS
    return GnssFix(r.t if t is None else t, xy, vel, sigma_h_of(r, hdop_uere_m), float(sigma_v))


def distance_m(a: GnssReading | AutopilotPosition, b: GnssReading | Origin) -> float:
    """Flat-earth distance between two positions (lat, lon degrees), metres (for plausibility checks)."""
    dn = (a.lat - b.lat) * M_PER_DEG
    de = (a.lon - b.lon) * M_PER_DEG * math.cos(math.radians(a.lat))
    return math.hypot(dn, de)


@dataclass(frozen=True)
class GnssEvent:
    """Something for events.jsonl (`kind`, `fields`) and, when `severity` is set, a STATUSTEXT `text`."""

    kind: str
    severity: int | None
    text: str
    fields: dict[str, Any] = field(default_factory=dict)


class GnssTracker:
    """See the module docstring. gps_id: output.gps_id (our instance is gps_id + 1); writes_gps: the profile
    sends a GPS-instance output (GPS_INPUT on ArduPilot, HIL_GPS on PX4; else no instance is ours); types:
    instance -> GPSn_TYPE, shared with the
    parameter check (filled as answers arrive); hdop_uere_m: output.hdop_uere_m for HDOP-only receivers."""

    def __init__(self, gps_id: int, writes_gps: bool, hdop_uere_m: float, types: dict[int, int] | None = None,
                 lost_after_s: float = 1.0, back_after_s: float = 1.0) -> None:
        self.ours = gps_id + 1 if writes_gps else None
        self.hdop_uere_m = hdop_uere_m
        self.types: dict[int, int] = types if types is not None else {}
        self.lost_after_s, self.back_after_s = lost_after_s, back_after_s
        self.counts: Counter[str] = Counter()
        self.state = "none"
        self.instance: int | None = None  # the real instance in use
        self.latest: GnssReading | None = None  # its latest usable 3D fix
        self.latest_at = -math.inf  # companion s
        self._heard: dict[int, float] = {}
        self._run_since: float | None = None  # start of the current run of 3D fixes
        self._steady: list[GnssReading] = []
        self._rejecting = False
        self._rejected_since: float | None = None

    # ------------------------------------------------------------------ instances
    def role(self, instance: int) -> str:
        """"ours" (our GPS_INPUT's echo), "mav" (another GPS_INPUT-fed instance), "none" (GPSn_TYPE 0) or
        "real"."""
        t = self.types.get(instance)
        if instance == self.ours and (t is None or t == GPS_TYPE_MAV):
            return "ours"
        if t == GPS_TYPE_MAV:
            return "mav"
        return "none" if t == GPS_TYPE_NONE else "real"

    def is_real(self, instance: int) -> bool:
        return self.role(instance) == "real"

    @property
    def rejecting(self) -> bool:
        """The Localiser is refusing the receiver's fixes (spoofed or glitching?)."""
        return self._rejecting

    @property
    def steady(self) -> bool:
        """The instance in use has given STEADY_FIXES consecutive, mutually consistent 3D fixes."""
        return len(self._steady) >= STEADY_FIXES

    def fresh(self, now: float) -> GnssReading | None:
        """The latest usable 3D fix when it is younger than lost_after_s (companion s), else None."""
        return self.latest if now - self.latest_at <= self.lost_after_s else None

    # ------------------------------------------------------------------ readings
    def on_message(self, instance: int, reading: GnssReading | None, fix_type: int, now: float,
                   origin: Origin | None = None) -> tuple[GnssReading | None, list[GnssEvent]]:
        """One GPS_RAW_INT / GPS2_RAW of instance `instance` arrived at companion time `now`; `reading` is the
        decoded 3D fix (None when the decoder refused it or there was no 3D fix: `fix_type` tells which).
        A fix farther than MAX_RANGE_M from `origin` is garbage: counted, otherwise ignored. Returns the reading
        to use (origin, fusion) or None, and the events it caused."""
        role = self.role(instance)
        if role != "real":
            self.counts[f"gps{instance}_{role}"] += 1
            return None, []
        if reading is not None and origin is not None and not distance_m(reading, origin) <= MAX_RANGE_M:
            self.counts["far_from_origin"] += 1
            return None, []
        self._heard[instance] = now
        if self.instance is None or (instance != self.instance and reading is not None
                                     and now - self.latest_at > self.lost_after_s):
            if self.instance is not None:
                log.info("real GNSS: GPS%d instead of GPS%d", instance, self.instance)
            self.instance, self._steady = instance, []
        if instance != self.instance:
            self.counts[f"gps{instance}_standby"] += 1
            return None, []
        if reading is None:
            if fix_type < 3:
                self._run_since, self._steady = None, []
                self.counts[f"gps{instance}_no_fix"] += 1
            return None, self.tick(now)
        if self._steady and distance_m(self._steady[-1], reading) > STEADY_STEP_M:
            self._steady = []
        self._steady = (self._steady + [reading])[-STEADY_FIXES:]
        self.latest, self.latest_at = reading, now
        if self._run_since is None:
            self._run_since = now
        self.counts[f"gps{instance}_fix"] += 1
        events: list[GnssEvent] = []
        if self.state == "none":
            self.state = "ok"
            log.info("real GNSS: GPS%d 3D fix", instance)
        elif self.state == "lost" and now - self._run_since >= self.back_after_s:
            self.state = "ok"
            events.append(GnssEvent("gnss_back", SEV_NOTICE, f"GPS{instance} back: 3D fix",
                                    {"instance": instance, "fix_type": reading.fix_type,
                                     "sigma_h_m": sigma_h_of(reading, self.hdop_uere_m)}))
        return reading, events

    def tick(self, now: float) -> list[GnssEvent]:
        """Periodic check (companion s): the real GNSS is lost after lost_after_s without a usable 3D fix."""
        if self.state != "ok" or now - self.latest_at <= self.lost_after_s:
            return []
        self.state = "lost"
        self._run_since, self._steady = None, []
        inst = self.instance
        silent = now - self._heard.get(inst, -math.inf) > self.lost_after_s if inst is not None else True
        why = "silent" if silent else "no_3d_fix"
        self.counts["lost"] += 1
        return [GnssEvent("gnss_lost", SEV_WARNING, f"GPS{inst} lost ({why.replace('_', ' ')}): camera+IMU",
                          {"instance": inst, "reason": why, "since_fix_s": now - self.latest_at})]

    def fix(self, r: GnssReading, origin: Origin, t_autopilot: float | None) -> GnssFix | None:
        """The reading as a GnssFix, stamped with its own time unless that is more than MAX_TIME_SKEW_S from
        `t_autopilot` (the autopilot's now, s; then now). None beyond MAX_RANGE_M of the origin."""
        t = r.t
        if t_autopilot is not None and not abs(t - t_autopilot) <= MAX_TIME_SKEW_S:
            self.counts["time_replaced"] += 1
            t = t_autopilot
        f = gnss_fix(r, origin, self.hdop_uere_m, t)
        if not float(np.hypot(*f.xy)) <= MAX_RANGE_M:  # on_message has counted it already (flat earth)
            return None
        return f

    def outcome(self, o: GnssOutcome, now: float) -> list[GnssEvent]:
        """What the Localiser did with one fix: the first rejection of a run and the first use after it are
        events (with the outcome's figures)."""
        self.counts[f"outcome_{o.reason}"] += 1
        figures = {"instance": self.instance, "reason": o.reason, "nis": o.nis, "window_nis": o.window_nis,
                   "innovation_m": o.innovation_m}
        if o.reason == "rejected" and not self._rejecting:
            self._rejecting, self._rejected_since = True, now
            return [GnssEvent("gnss_rejected", SEV_WARNING,
                              f"GPS{self.instance} REJECTED: {o.innovation_m:.0f}m off, spoofed?", figures)]
        if o.used and self._rejecting:
            self._rejecting = False
            rejected_s = now - (self._rejected_since or now)
            return [GnssEvent("gnss_accepted_again", SEV_NOTICE, f"GPS{self.instance} accepted again",
                              {**figures, "rejected_s": rejected_s})]
        return []

    def summary(self) -> dict[str, Any]:
        """Counters and state for the daemon's stats."""
        return {"state": self.state, "instance": self.instance, "rejecting": self._rejecting, **self.counts}
