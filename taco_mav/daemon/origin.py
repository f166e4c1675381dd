"""The daemon's handler of where the vehicle is in the world: the origin (--origin, the EKF origin, home, a
steady real GNSS; `OriginChooser` decides which and when), asking the autopilot for one while there is none,
and real GNSS readings (GPS_RAW_INT, GPS2_RAW), which give the start speed and course and are then fused by
the Localiser while they are honest (`GnssTracker`, the guard in the core)."""

from __future__ import annotations

import logging
from typing import Any, Callable

from taco_mav.config import Profile
from taco_mav.daemon.anchor import GNSS_RANK, NO_ORIGIN_TEXTS, OriginCandidate, OriginChooser
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.gnss import GnssEvent, GnssTracker
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.state import LiveState
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.decoders import GNSS_MESSAGES, ORIGIN_MESSAGES, Decoders, GnssReading
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_WARNING
from taco_mav.mavlink.requests import MessageRequest

log = logging.getLogger(__name__)

__all__ = ["OriginHandler"]


class OriginHandler:
    """state: shared (this handler sets the origin and the start, and hands GNSS to the Localiser);
    writes_gps: our output occupies GPS instance output.gps_id + 1 (never a receiver); clock: companion s."""

    def __init__(self, profile: Profile, state: LiveState, decoders: Decoders, fixes: FixPipeline,
                 reporter: Reporter, clock: Callable[[], float], writes_gps: bool) -> None:
        self.profile, self.state, self.decoders = profile, state, decoders
        self.fixes, self.reporter, self.clock = fixes, reporter, clock
        self.writes_gps = writes_gps
        self.chooser = OriginChooser()
        self.gnss = GnssTracker(profile.output.gps_id, writes_gps, profile.output.hdop_uere_m)
        self.link: Link | None = None
        self.request: MessageRequest | None = None  # GPS_GLOBAL_ORIGIN / HOME_POSITION while there is no origin

    def handlers(self) -> dict[str, Callable[[Any, float], None]]:
        out: dict[str, Callable[[Any, float], None]] = {k: self.on_gnss for k in GNSS_MESSAGES}
        out.update({k: self.on_origin_message for k in ORIGIN_MESSAGES})
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
        if c.rank == GNSS_RANK:
            self.state.anchor.set_start((0.0, 0.0), c.speed, c.course, None, c.t)  # carried to the first IMU sample
        elif (fresh := self.gnss.fresh(self.clock())) is not None:
            self._start_from_gnss(fresh)

    def _start_from_gnss(self, r: GnssReading) -> None:
        """Before the first anchoring: a real fix's speed and course, and its position if the vehicle has moved
        away from the offered origin (`Anchor.start_from_fix`)."""
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
        reading = self.decoders.gnss(msg) if self.gnss.is_real(instance) else None
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
