"""The daemon's origin and re-anchoring: the start position (--origin, EKF origin, home, a steady real GNSS),
autopilot reboots and IMU gaps, and real GNSS readings handed to the Localiser.

A mixin of `Daemon` (methods only, annotated `self: Daemon`): the loop thread owns all daemon state.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from taco_mav.daemon.anchor import GNSS_RANK, NO_ORIGIN_TEXTS, OriginCandidate
from taco_mav.daemon.gnss import GnssEvent
from taco_mav.mavlink import encoders
from taco_mav.mavlink.decoders import GNSS_MESSAGES, GnssReading
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_WARNING

if TYPE_CHECKING:
    from taco_mav.daemon.daemon import Daemon

log = logging.getLogger(__name__)

__all__ = ["DaemonOrigin"]


class DaemonOrigin:
    """Origin, re-anchoring and real-GNSS handling of `Daemon`."""

    @property
    def origin(self: Daemon) -> encoders.Origin | None:
        """The origin (start fix and UTM frame), None until one is taken."""
        return self.anchor.origin

    def _set_origin(self: Daemon, lat: float, lon: float, alt: float, speed: float, course: float | None,
                    source: str) -> None:
        """Take (lat, lon degrees, alt m) as the origin: log, event, STATUSTEXT, and tell the fix pipeline."""
        origin = self.anchor.set_origin(lat, lon, alt, speed, course)
        log.info("origin from %s: %.7f, %.7f, %.1f m (UTM EPSG:%d), speed %.2f m/s", source, lat, lon, alt,
                 origin.projector.epsg, speed)
        self.events.write("origin", source=source, lat=lat, lon=lon, alt=alt, speed=speed, course_ned=course,
                          epsg=origin.projector.epsg, convergence_rad=origin.convergence)
        self._status(SEV_INFO, f"origin {lat:.6f},{lon:.6f} ({source})", key=None)
        self.fixes.on_origin(origin)

    def _reboot(self: Daemon, t_last: float, t_new: float) -> None:
        """Autopilot clock went back: re-anchor at the current estimate on the new clock."""
        self.stats.reboots += 1
        text = f"autopilot reboot? time {t_last:.1f}s -> {t_new:.1f}s: re-anchored"
        log.warning("%s", text)
        self.events.write("reboot", t_last=t_last, t_new=t_new)
        self._status(SEV_WARNING, text, key="reboot")
        self.clockmap.reset()
        self.fixes.clear_truth()
        if self.loc is not None and self.attitude is not None:
            self.loc = self.anchor.restarted(self.loc, self.attitude.yaw, t_new)
        self.last_imu = None

    def _imu_gap(self: Daemon, t_last: float, t_new: float) -> None:
        """No IMU from t_last to t_new (autopilot s), longer than the preintegrator bridges (imu.max_dt_s): the
        motion in between is unknown. Re-anchor at the estimate carried on at its speed and heading, with the
        1-sigma grown over the gap, so the output stays degraded until fixes bring it back."""
        assert self.loc is not None and self.attitude is not None
        c = self.anchor.carried(self.loc, t_last, t_new)
        self.stats.imu_gaps += 1
        log.warning("IMU gap %.1f s: re-anchored %.1f m ahead, sigma %.1f m", t_new - t_last, abs(c.carried_m), c.sigma)
        self.events.write("imu_gap", t_last=t_last, t_new=t_new, sigma_h=c.sigma, carried_m=c.carried_m)
        self.loc = self.anchor.localiser(t_new, self.attitude.yaw, c.xy, c.heading, c.speed, c.sigma)

    def _offer_origin(self: Daemon, c: OriginCandidate) -> None:
        """An origin offered (--origin, EKF origin, home, a steady real GNSS): `OriginChooser` says when to take
        which."""
        chosen = self.origin_chooser.offer(c, self.clock())
        if chosen is not None:
            self._take_origin(chosen)

    def _take_origin(self: Daemon, c: OriginCandidate) -> None:
        """Take the chosen origin; a fresh real GNSS fix then gives the start speed, course and position."""
        self._set_origin(c.lat, c.lon, c.alt, c.speed, c.course, c.source)
        if c.rank == GNSS_RANK:
            self.anchor.set_start((0.0, 0.0), c.speed, c.course, None, c.t)  # carried to the first IMU sample
        elif (fresh := self.gnss.fresh(self.clock())) is not None:
            self._start_from_gnss(fresh)

    def _start_from_gnss(self: Daemon, r: GnssReading) -> None:
        """Before the first anchoring: a real fix's speed and course, and its position if the vehicle has moved
        away from the offered origin (`Anchor.start_from_fix`)."""
        assert self.origin is not None
        f = self.gnss.fix(r, self.origin, None)
        if f is not None and self.anchor.start_from_fix(f, r.speed, r.course_ned):
            self.events.write("start_from_gnss", instance=r.instance, x=float(f.xy[0]), y=float(f.xy[1]),
                              sigma_h_m=f.sigma_h_m)

    def _on_gnss(self: Daemon, msg: Any) -> None:
        """GPS_RAW_INT / GPS2_RAW: a real instance's 3D fix offers the origin, then goes to the Localiser
        (`add_gnss`); our own instance's echo is only counted (`GnssTracker`)."""
        instance, now = GNSS_MESSAGES[msg.get_type()], self.clock()
        reading = self.decoders.gnss(msg) if self.gnss.is_real(instance) else None
        r, events = self.gnss.on_message(instance, reading, int(msg.fix_type), now, self.origin)
        self._gnss_events(events)
        if r is None:
            return
        if self.origin is None:
            if self.gnss.steady:
                self._offer_origin(OriginCandidate(r.lat, r.lon, r.alt, r.speed, r.course_ned, msg.get_type(), r.t))
            return
        if self.loc is None:
            self._start_from_gnss(r)
            return
        fix = self.gnss.fix(r, self.origin, self.last_imu.t if self.last_imu is not None else None)
        if fix is not None:
            self._gnss_events(self.gnss.outcome(self.loc.add_gnss(fix), now))

    def _gnss_events(self: Daemon, events: list[GnssEvent]) -> None:
        """GNSS state changes: log, event and STATUSTEXT each."""
        for e in events:
            log.warning("%s", e.text) if e.severity == SEV_WARNING else log.info("%s", e.text)
            self.events.write(e.kind, **e.fields)
            self._status(e.severity if e.severity is not None else SEV_INFO, e.text, key=None)

    def _origin_tick(self: Daemon, now: float) -> None:
        """Periodic: take an origin whose grace ran out; while none, ask for GPS_GLOBAL_ORIGIN / HOME_POSITION
        and say every 10 s how to give one; GNSS loss by silence."""
        link = self.link
        assert link is not None
        if self.origin is None:
            if link.target_system:
                self.origin_chooser.heard(now)
            chosen = self.origin_chooser.poll(now)
            if chosen is not None:
                self._take_origin(chosen)
        if self.origin is None:
            self.origin_request.tick(now, link.target_system, link.target_component)
            if self.origin_chooser.notice_due(now):
                ours = f"GPS{self.profile.output.gps_id + 1}" if self.output.writes_gps else None
                log.warning("no origin yet: give one with --origin LAT,LON[,ALT], set the EKF origin or home from "
                            "the ground station, or connect a real GNSS with a 3D fix%s",
                            f" (not {ours}: that instance carries our own output)" if ours else "")
                self.events.write("no_origin", notices=self.origin_chooser.notices, gnss=self.gnss.summary())
                for text in NO_ORIGIN_TEXTS:
                    self._status(SEV_WARNING, text, key=None)
        self._gnss_events(self.gnss.tick(now))
