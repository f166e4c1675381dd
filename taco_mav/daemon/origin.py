"""The daemon's handler of where the vehicle is in the world: the origin (--origin, the EKF origin, home, a
steady real GNSS; `OriginChooser` decides which and when), asking the autopilot for one while there is none,
real GNSS readings (GPS_RAW_INT, GPS2_RAW), which give the start speed and course and are then fused by the
Localiser while they are honest (`GnssTracker`, the guard in the core), and the autopilot's own position
(GLOBAL_POSITION_INT): with no real GNSS, a daemon started beside a vehicle that already has one (a restart
mid-mission) starts there, with an honest 1-sigma, never at the origin."""

from __future__ import annotations

import logging
import math
from typing import Any, Callable

from taco_mav.config import Profile
from taco_mav.daemon.anchor import (AUTOPILOT_START_SIGMA_M, GNSS_RANK, NO_ORIGIN_TEXTS, START_POSITION_WAIT_S,
                                    OriginCandidate, OriginChooser)
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.gnss import MAX_RANGE_M, GnssEvent, GnssTracker, distance_m
from taco_mav.daemon.output_stage import writes_gps
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.shadow import SHADOW_NAME
from taco_mav.daemon.state import LiveState
from taco_mav.mavlink import encoders
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.decoders import (GNSS_MESSAGES, ORIGIN_MESSAGES, POSITION_MESSAGE, AutopilotPosition,
                                       Decoders, GnssReading)
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_WARNING
from taco_mav.mavlink.requests import MessageRequest

log = logging.getLogger(__name__)

__all__ = ["OriginHandler"]


class OriginHandler:
    """state: shared (this handler sets the origin and the start, and hands GNSS to the Localiser); fixes: told
    the origin (its map frame); clock: companion s. When our output is a GPS instance (`writes_gps`), it occupies
    instance output.gps_id + 1, never a receiver."""

    def __init__(self, *, profile: Profile, state: LiveState, decoders: Decoders, fixes: FixPipeline,
                 reporter: Reporter, clock: Callable[[], float]) -> None:
        self.profile, self.state, self.decoders = profile, state, decoders
        self.fixes, self.reporter, self.clock = fixes, reporter, clock
        self.writes_gps = writes_gps(profile.output)
        self.chooser = OriginChooser()
        self.gnss = GnssTracker(profile.output.gps_id, self.writes_gps, profile.output.hdop_uere_m)
        self.link: Link | None = None
        self.request: MessageRequest | None = None  # GPS_GLOBAL_ORIGIN / HOME_POSITION while there is no origin
        self.position: AutopilotPosition | None = None  # the autopilot's latest own position
        self.position_at = -math.inf  # companion s it came
        self.echo_h_acc: float | None = None  # m: the 1-sigma our GPS instance last showed (our previous run's)

    def handlers(self) -> dict[str, Callable[[Any, float], None]]:
        out: dict[str, Callable[[Any, float], None]] = {k: self.on_gnss for k in GNSS_MESSAGES}
        out.update({k: self.on_origin_message for k in ORIGIN_MESSAGES})
        out[POSITION_MESSAGE] = self.on_position
        return out

    def open(self, link: Link, gps_types: dict[int, int] | None,
             origin: tuple[float, float, float] | None) -> None:
        """The session's link is up. gps_types: the autopilot's GPSn_TYPE as the parameter check reads them
        (which instances are receivers); origin: `--origin` (lat, lon degrees, alt m), offered at once."""
        self.link = link
        if gps_types is not None:
            self.gnss.types = gps_types
        self.request = MessageRequest(link.send, link.mav, ORIGIN_MESSAGES)
        if origin is not None:
            self.offer(OriginCandidate(*origin, speed=0.0, course=None, source="--origin"))

    # ------------------------------------------------------------------ origin
    def offer(self, c: OriginCandidate) -> None:
        """An origin offered (--origin, EKF origin, home, a steady real GNSS): `OriginChooser` says when to take
        which."""
        chosen = self.chooser.offer(c, self.clock())
        if chosen is not None:
            self._take(chosen)

    def on_origin_message(self, msg: Any, received: float) -> None:
        """GPS_GLOBAL_ORIGIN / HOME_POSITION, while there is no origin yet."""
        o = self.decoders.origin(msg) if self.state.origin is None else None
        if o is not None:
            self.offer(OriginCandidate(o.lat, o.lon, o.alt, 0.0, None, o.source))

    def _take(self, c: OriginCandidate) -> None:
        """Take the chosen origin (log, event, STATUSTEXT, the fix pipeline's map frame); a fresh real GNSS fix
        then gives the start speed, course and position."""
        origin = self.state.anchor.set_origin(c.lat, c.lon, c.alt, c.speed, c.course)
        log.info("origin from %s: %.7f, %.7f, %.1f m (UTM EPSG:%d), speed %.2f m/s", c.source, c.lat, c.lon, c.alt,
                 origin.projector.epsg, c.speed)
        self.reporter.event("origin", source=c.source, lat=c.lat, lon=c.lon, alt=c.alt, speed=c.speed,
                            course_ned=c.course, epsg=origin.projector.epsg, convergence_rad=origin.convergence)
        self.reporter.status(SEV_INFO, f"origin {c.lat:.6f},{c.lon:.6f} ({c.source})")
        self.fixes.on_origin(origin)
        now = self.clock()
        if c.rank == GNSS_RANK:
            self.state.anchor.set_start((0.0, 0.0), c.speed, c.course, None, c.t)  # carried to the first IMU sample
            self.state.anchor.start_source = "gnss"
        elif (fresh := self.gnss.fresh(now)) is not None:
            self._start_from_gnss(fresh)
        elif self.position is not None and now - self.position_at <= START_POSITION_WAIT_S:
            self._start_from_autopilot(self.position)
        else:
            self.state.anchor.hold_start(now + START_POSITION_WAIT_S)

    def on_position(self, msg: Any, received: float) -> None:
        """GLOBAL_POSITION_INT: the autopilot's own position; before the first anchoring it is the start when no
        real GNSS gives one (`LocaliserAnchor.start_from_autopilot`)."""
        p = self.decoders.autopilot_position(msg)
        if p is None:
            return
        self.position, self.position_at = p, self.clock()
        if self.state.origin is not None and self.state.loc is None:
            self._start_from_autopilot(p)

    def _start_from_autopilot(self, p: AutopilotPosition) -> None:
        """Start where the autopilot says the vehicle is, 1-sigma the larger of AUTOPILOT_START_SIGMA_M and the
        accuracy our GPS instance last showed (what the previous run reported)."""
        origin = self.state.origin
        assert origin is not None
        if not distance_m(p, origin) <= MAX_RANGE_M:  # PX4 sends one before EKF2 has a global origin: no position
            self.decoders.reject(POSITION_MESSAGE, "far_from_origin")
            return
        x, y = origin.xy(p.lat, p.lon)
        xy = (float(x), float(y))
        sigma = max(AUTOPILOT_START_SIGMA_M, self.echo_h_acc or 0.0)
        if self.state.anchor.start_from_autopilot(xy, p.speed, p.course_ned, p.t, sigma):
            dist = math.hypot(*xy)
            log.warning("starting at the autopilot's position, %.1f m from the origin at %.1f m/s, 1-sigma %.1f m",
                        dist, p.speed, sigma)
            self.reporter.event("start_from_autopilot", x=xy[0], y=xy[1], speed=p.speed, course_ned=p.course_ned,
                                sigma_h_m=sigma, echo_h_acc_m=self.echo_h_acc)
            self.reporter.status(SEV_WARNING, f"start at autopilot pos {dist:.0f}m from origin, sigma {sigma:.1f}m")

    def _start_from_gnss(self, r: GnssReading) -> None:
        """Before the first anchoring: a real fix's speed and course, and its position if the vehicle has moved
        away from the offered origin (`LocaliserAnchor.start_from_fix`)."""
        origin = self.state.origin
        assert origin is not None
        f = self.gnss.fix(r, origin, None)
        if f is not None and self.state.anchor.start_from_fix(f, r.speed, r.course_ned):
            self.reporter.event("start_from_gnss", instance=r.instance, x=float(f.xy[0]), y=float(f.xy[1]),
                                sigma_h_m=f.sigma_h_m)

    # ------------------------------------------------------------------ GNSS
    def on_gnss(self, msg: Any, received: float) -> None:
        """GPS_RAW_INT / GPS2_RAW: a real instance's 3D fix offers the origin, then goes to the Localiser
        (`add_gnss`); our own instance's echo is only counted (`GnssTracker`)."""
        st = self.state
        instance, now = GNSS_MESSAGES[msg.get_type()], self.clock()
        real = self.gnss.is_real(instance)
        reading = self.decoders.gnss(msg) if real else None
        if not real and st.loc is None and int(msg.fix_type) >= 3:  # our echo: what our previous run last reported
            echo = self.decoders.gnss(msg)
            if echo is not None and echo.h_acc_m is not None:
                self.echo_h_acc = echo.h_acc_m
        r, events = self.gnss.on_message(instance, reading, int(msg.fix_type), now, st.origin)
        self._events(events)
        if r is None:
            return
        if st.origin is None:
            if self.gnss.steady:
                self.offer(OriginCandidate(r.lat, r.lon, r.alt, r.speed, r.course_ned, msg.get_type(), r.t))
            return
        if st.loc is None:
            self._start_from_gnss(r)
            return
        fix = self.gnss.fix(r, st.origin, st.last_imu.t if st.last_imu is not None else None)
        if fix is not None:
            self._events(self.gnss.outcome(st.loc.add_gnss(fix), now))

    def _events(self, events: list[GnssEvent]) -> None:
        """GNSS state changes: log, event and STATUSTEXT each."""
        for e in events:
            log.warning("%s", e.text) if e.severity == SEV_WARNING else log.info("%s", e.text)
            self.reporter.event(e.kind, **e.fields)
            self.reporter.status(e.severity if e.severity is not None else SEV_INFO, e.text)

    # ------------------------------------------------------------------ periodic
    def tick(self, now: float) -> None:
        """Take an origin whose grace ran out; while none, ask for GPS_GLOBAL_ORIGIN / HOME_POSITION and say
        every 10 s how to give one; GNSS loss by silence."""
        link, st = self.link, self.state
        assert link is not None and self.request is not None
        if st.origin is None:
            if link.target_system:
                self.chooser.heard(now)
            chosen = self.chooser.poll(now)
            if chosen is not None:
                self._take(chosen)
        if st.origin is None:
            self.request.tick(now, link.target_system, link.target_component)
            if self.chooser.notice_due(now):
                ours = f"GPS{self.profile.output.gps_id + 1}" if self.writes_gps else None
                log.warning("no origin yet: give one with --origin LAT,LON[,ALT], set the EKF origin or home from "
                            "the ground station, or connect a real GNSS with a 3D fix%s",
                            f" (not {ours}: that instance carries our own output)" if ours else "")
                self.reporter.event("no_origin", notices=self.chooser.notices, gnss=self.gnss.summary())
                for text in NO_ORIGIN_TEXTS:
                    self.reporter.status(SEV_WARNING, text)
        self._events(self.gnss.tick(now))
        if st.shadow is not None and st.shadow.due():
            self._shadow(now)

    def _shadow(self, now: float) -> None:
        """Shadow mode's 1 Hz report: the GNSS-free twin against an honest receiver's latest fix (`shadow`
        event, NAMED_VALUE_FLOAT taco_shad); nothing while the receiver is lost or refused."""
        st, link = self.state, self.link
        assert st.shadow is not None and link is not None
        r = self.gnss.fresh(now) if self.gnss.state == "ok" and not self.gnss.rejecting else None
        fix = None
        if r is not None and st.origin is not None:
            fix = self.gnss.fix(r, st.origin, st.last_imu.t if st.last_imu is not None else None)
        fields = st.shadow.compare(fix, st.origin)
        if fields is None:
            return
        self.reporter.event("shadow", **fields)
        link.send(encoders.named_value_float(link.mav, int(fields["t"] * 1e3), SHADOW_NAME, fields["gnss_err_m"]))
