"""Where the daemon's Localiser starts and restarts: the origin (the start-up GNSS reading or --origin), the
first anchoring, and re-anchoring after an autopilot reboot or an IMU gap. Pure bookkeeping and geometry; the
daemon writes the events and STATUSTEXTs.

World frame: ENU metres relative to the origin; headings ENU (UTM grid) radians; times autopilot seconds.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

from taco_mav.core.localiser import Localiser
from taco_mav.core.localiser_plus import make_localiser
from taco_mav.core.params import LocaliserParams
from taco_mav.link import encoders
from taco_mav.link.health import stall_sigma

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Carried:
    """The estimate carried across an IMU gap: xy (ENU m), heading (rad), speed (m/s), sigma (1-sigma m),
    carried_m (the distance moved on at the last speed, m)."""

    xy: tuple[float, float]
    heading: float
    speed: float
    sigma: float
    carried_m: float


class Anchor:
    """The origin and the Localiser generations. `generation` goes up by one at each (re-)anchoring, so fixes
    asked for by an older Localiser can be dropped."""

    def __init__(self, params: LocaliserParams) -> None:
        self.params = params
        self.origin: encoders.Origin | None = None
        self.start_speed = 0.0  # m/s, from the start-up GNSS reading
        self.start_course: float | None = None  # NED rad, course over ground at start-up
        self.generation = 0

    def set_origin(self, lat: float, lon: float, alt: float, speed: float, course: float | None) -> encoders.Origin:
        """The origin (WGS-84 degrees, metres above the ellipsoid) with the start speed and course."""
        self.origin = encoders.Origin.from_latlon(lat, lon, alt)
        self.start_speed, self.start_course = speed, course
        return self.origin

    def localiser(self, t: float, attitude_yaw: float, xy: tuple[float, float] = (0.0, 0.0),
                  heading: float | None = None, speed: float | None = None,
                  sigma_xy: float | None = None) -> Localiser:
        """A new Localiser at autopilot time t. Without `heading` the start course over ground is used when the
        vehicle was moving (> 1 m/s), else the attitude yaw (NED rad); sigma_xy (m) overrides the initial
        1-sigma (re-anchoring keeps the uncertainty it had)."""
        assert self.origin is not None
        conv = self.origin.convergence
        if heading is None:
            use_course = self.start_course is not None and self.start_speed > 1.0
            psi = self.start_course if use_course else attitude_yaw
            heading = math.remainder(math.pi / 2 - psi + conv, 2 * math.pi)
        params = self.params if sigma_xy is None else dataclasses.replace(self.params, initial_sigma_xy_m=sigma_xy)
        loc = make_localiser(params, t, xy[0], xy[1], heading, self.start_speed if speed is None else speed,
                             record=False, heading_offset=conv)
        self.generation += 1
        log.info("localiser anchored at t=%.3f s, xy (%.1f, %.1f) m, heading %.1f deg", t, xy[0], xy[1],
                 math.degrees(heading))
        return loc

    def restarted(self, loc: Localiser, attitude_yaw: float, t_new: float) -> Localiser:
        """After an autopilot reboot (its clock went back): a Localiser on the new clock at the current estimate,
        keeping its 1-sigma."""
        est = loc.estimate()
        return self.localiser(t_new, attitude_yaw, (float(est.xy[0]), float(est.xy[1])), est.theta, est.speed,
                              max(est.sigma_h, self.params.initial_sigma_xy_m))

    def carried(self, loc: Localiser, t_last: float, t_new: float) -> Carried:
        """No IMU from t_last to t_new: the estimate carried on at its speed and heading, its 1-sigma grown
        over the gap (`stall_sigma`)."""
        est = loc.estimate()
        speed = est.speed if math.isfinite(est.speed) else 0.0
        d = speed * (t_new - est.t)
        xy = (float(est.xy[0]) + d * math.cos(est.theta), float(est.xy[1]) + d * math.sin(est.theta))
        sigma = max(stall_sigma(est.sigma_h, speed, t_new - t_last), self.params.initial_sigma_xy_m)
        return Carried(xy, est.theta, speed, sigma, d)
