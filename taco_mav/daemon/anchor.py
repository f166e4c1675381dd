"""Where the daemon's Localiser starts and restarts: the origin (chosen by `OriginChooser` from --origin, the
EKF origin, home or a real GNSS), the first anchoring, and re-anchoring after an autopilot reboot or an IMU
gap. Pure bookkeeping and geometry; the daemon writes the events and STATUSTEXTs.

World frame: ENU metres relative to the origin; headings ENU (UTM grid) radians; times autopilot seconds.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

from taco_mav.core.localiser import Localiser
from taco_mav.core.localiser import make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.core.types import GnssFix
from taco_mav.daemon.gnss import START_NEAR_M, moved_from_origin
from taco_mav.daemon.health import stall_sigma
from taco_mav.mavlink import encoders

log = logging.getLogger(__name__)


# Origin sources, best first: what the user gave, the EKF origin, home, a real GNSS with a 3D fix.
ORIGIN_RANK = {"--origin": 0, "GPS_GLOBAL_ORIGIN": 1, "HOME_POSITION": 2}
GNSS_RANK = 3  # any real GNSS instance ("GPS_RAW_INT", "GPS2_RAW")
NO_ORIGIN_TEXTS = ("no origin: set EKF origin/home in the GCS", "or --origin LAT,LON[,ALT] or a GNSS 3D fix")
MAX_START_CARRY_S = 2.0  # a start fix is carried at its speed and course to the first IMU sample, this far at most
# With no real GNSS, the first anchoring waits this long (companion s) after the origin is taken for the
# autopilot's own position (GLOBAL_POSITION_INT, asked for with the origin at 2 Hz; ArduPilot and PX4 answer
# within 0.5 s), so a daemon restarted mid-mission never starts at the origin.
START_POSITION_WAIT_S = 1.5
# 1-sigma of a start taken from the autopilot's position: its EKF's error while we fed it (1.0-1.5 m RMS on
# ArduPilot Rover SITL, docs/results.md) plus what it dead-reckoned while no daemon ran (a restart: seconds at up to
# 3 m/s). A camera fix brings it down within one trigger.
AUTOPILOT_START_SIGMA_M = 3.0
MOVING_MPS = 0.5  # an autopilot position at the origin starts there only when the vehicle is slower than this


@dataclass(frozen=True)
class OriginCandidate:
    """An offered origin: lat, lon degrees WGS84; alt metres AMSL; speed m/s and course_ned rad (0 = north,
    CW; None = unknown) at that moment; source: "--origin", a message name; t: autopilot s of a GNSS reading
    (None: a fixed point)."""

    lat: float
    lon: float
    alt: float
    speed: float
    course: float | None
    source: str
    t: float | None = None

    @property
    def rank(self) -> int:
        return ORIGIN_RANK.get(self.source, GNSS_RANK)


class OriginChooser:
    """Picks the origin from what is offered, best source first (ORIGIN_RANK). --origin and the EKF origin are
    taken at once; a lower-ranked offer waits until `grace_s` (companion s) have passed since the autopilot was
    heard (`heard(now)`: the EKF origin and home are asked for then) and `settle_s` since the first offer (an
    autopilot answering both requests at once), and then the best source's latest offer is taken. While
    nothing is chosen, `notice_due(now)` says when to tell the user how to give one: first `notice_first_s`
    after the autopilot was heard, then every `notice_every_s`."""

    def __init__(self, grace_s: float = 0.5, settle_s: float = 0.2, notice_first_s: float = 3.0,
                 notice_every_s: float = 10.0) -> None:
        self.grace_s, self.settle_s = grace_s, settle_s
        self.notice_first_s, self.notice_every_s = notice_first_s, notice_every_s
        self.chosen: OriginCandidate | None = None
        self.notices = 0
        self._offers: dict[int, OriginCandidate] = {}
        self._heard_at: float | None = None
        self._first_offer: float | None = None
        self._next_notice: float | None = None

    def offer(self, c: OriginCandidate, now: float) -> OriginCandidate | None:
        """Record an offer; returns the candidate to take now (None: wait or already chosen)."""
        if self.chosen is not None:
            return None
        self._offers[c.rank] = c
        if self._heard_at is None:
            self._heard_at = now
        if self._first_offer is None:
            self._first_offer = now
        return self.poll(now)

    def poll(self, now: float) -> OriginCandidate | None:
        """The candidate to take now, if any (call periodically: the grace may have run out)."""
        if self.chosen is not None or not self._offers:
            return None
        best = self._offers[min(self._offers)]
        assert self._heard_at is not None and self._first_offer is not None
        waited = now - self._heard_at >= self.grace_s and now - self._first_offer >= self.settle_s
        if best.rank <= ORIGIN_RANK["GPS_GLOBAL_ORIGIN"] or waited:
            self.chosen = best
            return best
        return None

    def heard(self, now: float) -> None:
        """The autopilot is reachable: start the grace and the no-origin notices' clocks (once)."""
        if self._heard_at is None:
            self._heard_at = now
        if self._next_notice is None:
            self._next_notice = now + self.notice_first_s

    def notice_due(self, now: float) -> bool:
        """True when the "no origin" notice is due (never once an origin is chosen)."""
        if self.chosen is not None or self._next_notice is None or now < self._next_notice:
            return False
        self._next_notice = now + self.notice_every_s
        self.notices += 1
        return True


@dataclass(frozen=True)
class Carried:
    """The estimate carried across an IMU gap: xy (ENU m), heading (rad), speed (m/s), sigma (1-sigma m),
    carried_m (the distance moved on at the last speed, m)."""

    xy: tuple[float, float]
    heading: float
    speed: float
    sigma: float
    carried_m: float


class LocaliserAnchor:
    """The origin and the Localiser generations. `generation` goes up by one at each (re-)anchoring, so fixes
    asked for by an older Localiser can be dropped."""

    def __init__(self, params: LocaliserParams) -> None:
        self.params = params
        self.origin: encoders.Origin | None = None
        self.start_speed = 0.0  # m/s, from the start-up GNSS reading
        self.start_course: float | None = None  # NED rad, course over ground at start-up
        self.start_xy: tuple[float, float] = (0.0, 0.0)  # ENU m: where the first Localiser starts
        self.start_sigma: float | None = None  # m: its initial 1-sigma (None: the profile's)
        self.start_t: float | None = None  # autopilot s at which the vehicle was at start_xy (None: it rests there)
        self.start_source: str | None = None  # what placed the start: "gnss", "autopilot" (None: the origin)
        self.generation = 0
        self._hold_until: float | None = None  # companion s: the first anchoring waits for a start until then
        self._made: tuple[LocaliserParams, float, tuple[float, float], float, float, float] | None = None

    def set_origin(self, lat: float, lon: float, alt: float, speed: float, course: float | None) -> encoders.Origin:
        """The origin (WGS-84 degrees, metres above the ellipsoid) with the start speed and course."""
        self.origin = encoders.Origin.from_latlon(lat, lon, alt)
        self.start_speed, self.start_course = speed, course
        return self.origin

    def set_start(self, xy: tuple[float, float], speed: float, course: float | None, sigma: float | None,
                  t: float | None = None) -> None:
        """Start the first Localiser at xy (ENU m from the origin) with this speed (m/s), course (NED rad) and
        1-sigma (m), where a real GNSS fix put the vehicle at autopilot time t (s; None: no time, no carry)."""
        self.start_xy, self.start_speed, self.start_course, self.start_sigma = xy, speed, course, sigma
        self.start_t = t

    def start_from_fix(self, f: GnssFix, speed: float, course: float | None) -> bool:
        """A real GNSS fix before the first anchoring, with its speed (m/s) and course (NED rad): the start takes
        them, and the fix's position and accuracy when the vehicle is no longer at the offered origin
        (`gnss.moved_from_origin`). True when the start moved to the fix."""
        self._hold_until = None
        self.start_source = "gnss"
        if moved_from_origin(f):
            self.set_start((float(f.xy[0]), float(f.xy[1])), speed, course, f.sigma_h_m, f.t)
            return True
        self.set_start(self.start_xy, speed, course, self.start_sigma)  # still at the origin, within its accuracy
        return False

    def start_from_autopilot(self, xy: tuple[float, float], speed: float, course: float | None, t: float,
                             sigma: float) -> bool:
        """The autopilot's own position before the first anchoring: xy ENU m from the origin at autopilot time t
        (s), speed m/s, course NED rad, 1-sigma m. The start moves there (the daemon restarted beside a vehicle
        that has moved on) unless the vehicle rests at the origin (within START_NEAR_M, slower than
        MOVING_MPS), where the origin's start stands. A real GNSS start is never overridden. True when moved."""
        self._hold_until = None
        if self.start_source == "gnss":
            return False
        if math.hypot(*xy) <= START_NEAR_M and speed < MOVING_MPS:
            return False
        self.set_start(xy, speed, course, sigma, t)
        self.start_source = "autopilot"
        return True

    def hold_start(self, until: float) -> None:
        """Let the first anchoring wait until `until` (companion s) for the autopilot's position."""
        self._hold_until = until

    def holding(self, now: float) -> bool:
        """True while the first anchoring waits for a start (`hold_start`; `now` companion s)."""
        return self._hold_until is not None and now < self._hold_until

    def _start_at(self, t: float) -> tuple[float, float]:
        """The start position carried from start_t to t (s) at the start speed and course (up to
        MAX_START_CARRY_S; a vehicle moving between its fix and the first IMU sample)."""
        x, y = self.start_xy
        dt = 0.0 if self.start_t is None else t - self.start_t
        if self.start_course is None or not 0.0 < dt <= MAX_START_CARRY_S or self.origin is None:
            return x, y
        angle = math.pi / 2 - self.start_course + self.origin.convergence  # grid ENU
        d = self.start_speed * dt
        return x + d * math.cos(angle), y + d * math.sin(angle)

    def localiser(self, t: float, attitude_yaw: float, xy: tuple[float, float] | None = None,
                  heading: float | None = None, speed: float | None = None,
                  sigma_xy: float | None = None) -> Localiser:
        """A new Localiser at autopilot time t, at xy (ENU m; default the start position). Without `heading` the
        start course over ground is used when the vehicle was moving (> 1 m/s), else the attitude yaw (NED
        rad); sigma_xy (m) overrides the initial 1-sigma (re-anchoring keeps the uncertainty it had; the first
        anchoring takes the start's)."""
        assert self.origin is not None
        if xy is None:
            xy, sigma_xy = self._start_at(t), self.start_sigma if sigma_xy is None else sigma_xy
        conv = self.origin.convergence
        if heading is None:
            use_course = self.start_course is not None and self.start_speed > 1.0
            psi = self.start_course if use_course else attitude_yaw
            heading = math.remainder(math.pi / 2 - psi + conv, 2 * math.pi)
        params = self.params if sigma_xy is None else dataclasses.replace(
            self.params, ukf=dataclasses.replace(self.params.ukf, initial_sigma_xy_m=sigma_xy))
        self._made = (params, t, (float(xy[0]), float(xy[1])), heading,
                      self.start_speed if speed is None else speed, conv)
        loc = self._build()
        self.generation += 1
        log.info("localiser anchored at t=%.3f s, xy (%.1f, %.1f) m, heading %.1f deg", t, xy[0], xy[1],
                 math.degrees(heading))
        return loc

    def twin(self) -> Localiser:
        """A Localiser exactly as the last one `localiser` made (shadow mode's GNSS-free twin starts with it)."""
        return self._build()

    def _build(self) -> Localiser:
        """A Localiser from the arguments `localiser` last worked out."""
        assert self._made is not None
        params, t, xy, heading, speed, conv = self._made
        return make_localiser(params, t, xy[0], xy[1], heading, speed, record=False, heading_offset=conv)

    def restarted(self, loc: Localiser, attitude_yaw: float, t_new: float) -> Localiser:
        """After an autopilot reboot (its clock went back): a Localiser on the new clock at the current estimate,
        keeping its 1-sigma (the larger of the reported one and the filter's own, which a calibrated report can
        undercut)."""
        est = loc.estimate()
        return self.localiser(t_new, attitude_yaw, (float(est.xy[0]), float(est.xy[1])), est.theta, est.speed,
                              max(est.sigma_h, est.filter_sigma_h, self.params.ukf.initial_sigma_xy_m))

    def carried(self, loc: Localiser, t_last: float, t_new: float) -> Carried:
        """No IMU from t_last to t_new: the estimate carried on at its speed and heading, its 1-sigma grown
        over the gap (`stall_sigma`)."""
        est = loc.estimate()
        speed = est.speed if math.isfinite(est.speed) else 0.0
        d = speed * (t_new - est.t)
        xy = (float(est.xy[0]) + d * math.cos(est.theta), float(est.xy[1]) + d * math.sin(est.theta))
        sigma = max(stall_sigma(max(est.sigma_h, est.filter_sigma_h), speed, t_new - t_last),
                    self.params.ukf.initial_sigma_xy_m)
        return Carried(xy, est.theta, speed, sigma, d)
