"""The daemon's wheel encoders: WHEEL_DISTANCE from the autopilot (asked for at wheels.rate_hz when the profile
enables them) differenced into speeds and a yaw rate (core/wheel_odometry.py) and handed to taco+
(`Localiser.aids.add_wheel_speed`, core/plus/wheel_speed.py), which checks each against the filter and the gyro.

A source that goes wrong is told once per episode, as an event in events.jsonl and a STATUSTEXT:
- "wheels_quiet": no WHEEL_DISTANCE for wheels.quiet_s (companion s; also when none came since the session opened
  plus a grace), and "wheels_back" when one comes again;
- "wheels_refused" with the reason: a distance step implying more than wheels.max_speed_mps ("jump", the sample
  is refused and differencing starts again from it), or taco+ refusing the source ("slip", "stuck",
  "disagrees"); "wheels_resumed" when taco+ takes it again.
The wheels' lateral positions come from the profile, or from the autopilot's WENC_POS_Y / WENC2_POS_Y
(wheels.pos_y_from_autopilot, read by `AutopilotLink`). Times autopilot seconds unless said otherwise.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, Callable

from taco_mav.config import Profile
from taco_mav.core.wheel_odometry import WheelOdometry
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.state import LiveState
from taco_mav.mavlink.decoders import WHEEL_MESSAGE, Decoders
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_WARNING

log = logging.getLogger(__name__)

__all__ = ["STARTUP_GRACE_S", "WheelInput"]

STARTUP_GRACE_S = 10.0  # companion s after the first IMU sample before wheels that never spoke are quiet


class WheelInput:
    """profile: its `wheels` section; state: the Localiser and the shadow twin fed; pos_y: the wheels' lateral
    positions the autopilot reports (FRD metres), None until read (only with wheels.pos_y_from_autopilot)."""

    def __init__(self, *, profile: Profile, state: LiveState, decoders: Decoders, reporter: Reporter,
                 pos_y: Callable[[], tuple[float, float] | None]) -> None:
        self.w = profile.wheels
        self.state, self.decoders, self.reporter, self._pos_y = state, decoders, reporter, pos_y
        self.odometry = WheelOdometry(self.w.wheel_pos_y_m, self.w.max_speed_mps)
        self.geometry_known = not self.w.pos_y_from_autopilot
        self.counts: Counter[str] = Counter()  # verdicts and refusals
        self.refused: str | None = None  # the refusal told last (None: in use)
        self.quiet = False
        self._heard: float | None = None  # companion s of the last WHEEL_DISTANCE
        self._since: float | None = None  # companion s of the first watch

    def handlers(self) -> dict[str, Callable[[Any, float], None]]:
        return {WHEEL_MESSAGE: self.on_wheel_distance} if self.w.enabled else {}

    def on_wheel_distance(self, msg: Any, received: float) -> None:
        """One WHEEL_DISTANCE: differenced, checked and handed to taco+ (and its shadow twin)."""
        r = self.decoders.wheel_distance(msg)
        if r is None:
            return
        self._learn_geometry()
        if self.quiet:
            self.quiet = False
            self.reporter.event("wheels_back", silent_s=self._silence())
            self.reporter.status(SEV_INFO, "wheels back")
        self._heard = self._now()
        m = self.odometry.add(r.t, r.distances)
        if isinstance(m, str):
            self.counts[m] += 1
            if m == "jump":
                self._tell("jump", t=r.t, distances=list(r.distances))
            return
        loc = self.state.loc
        if loc is None or loc.aids is None:
            self.counts["no_filter"] += 1
            return
        verdict = loc.aids.add_wheel_speed(m)
        if self.state.twin is not None and self.state.twin.aids is not None:
            self.state.twin.aids.add_wheel_speed(m)
        self.counts[verdict] += 1
        refused = loc.aids.wheels_refused()
        if refused != self.refused:
            if refused is None:
                self.refused = None
                self.reporter.event("wheels_resumed", t=m.t1)
                self.reporter.status(SEV_INFO, "wheels in use again")
            else:
                self._tell(refused, t=m.t1, speed_mps=round(m.speed, 3),
                           yaw_rate_rps=None if m.yaw_rate is None else round(m.yaw_rate, 4))

    def watch(self, now: float) -> None:
        """At companion time `now` (s; the daemon's IMU path calls it): silence beyond wheels.quiet_s is quiet."""
        if not self.w.enabled:
            return
        if self._since is None:
            self._since = now
        last = self._heard if self._heard is not None else self._since + STARTUP_GRACE_S
        if not self.quiet and now - last > self.w.quiet_s:
            self.quiet = True
            silent = self._silence(now)
            log.warning("wheels quiet: no WHEEL_DISTANCE for %s s", silent)
            self.reporter.event("wheels_quiet", silent_s=silent, heard=self._heard is not None)
            self.reporter.status(SEV_WARNING, "wheels quiet: no WHEEL_DISTANCE", key="wheels_quiet")

    def _tell(self, reason: str, **fields: Any) -> None:
        """An event and a STATUSTEXT (rate-limited per reason) for a refusal."""
        if reason != "jump":
            self.refused = reason
        log.warning("wheels refused: %s", reason)
        self.reporter.event("wheels_refused", reason=reason, **fields)
        self.reporter.status(SEV_WARNING, f"wheels refused: {reason}", key=f"wheels_{reason}")

    def _learn_geometry(self) -> None:
        """Take the autopilot's wheel positions once they were read (wheels.pos_y_from_autopilot)."""
        if self.geometry_known:
            return
        pos_y = self._pos_y()
        if pos_y is None:
            return
        self.geometry_known = True
        self.odometry.set_pos_y(pos_y)
        self.reporter.event("wheels_geometry", pos_y_m=list(pos_y), source="WENC_POS_Y, WENC2_POS_Y")

    def _now(self) -> float:
        return self.reporter.clock()

    def _silence(self, now: float | None = None) -> float | None:
        """Companion s since the last WHEEL_DISTANCE (or since watching began), None before either."""
        now = self._now() if now is None else now
        last = self._heard if self._heard is not None else self._since
        return round(now - last, 2) if last is not None else None
