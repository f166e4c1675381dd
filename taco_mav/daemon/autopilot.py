"""The daemon's handler of the autopilot itself: adopting it (HEARTBEAT), our own HEARTBEAT, time sync
(TIMESYNC, SYSTEM_TIME), the stream requests and the parameter check (COMMAND_ACK, PARAM_VALUE), and whether
the link is alive. The other handlers only ever see messages from the autopilot adopted here."""

from __future__ import annotations

import logging
import math
from typing import Any, Callable

from taco_mav.config import Profile
from taco_mav.daemon.health import LinkWatch
from taco_mav.daemon.imu_source import ATTITUDE_REQUESTED, IMU_REQUESTED
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.scheduler import Periodic
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.decoders import WHEEL_POS_PARAMS
from taco_mav.mavlink.mavconst import (
    MAV_AUTOPILOT_INVALID,
    MAV_AUTOPILOT_PX4,
    MAV_TYPE_GCS,
    MAV_TYPE_ONBOARD_CONTROLLER,
    SEV_ERROR,
    SEV_WARNING,
)
from taco_mav.mavlink.param_read import ParamRead
from taco_mav.mavlink.requests import GNSS_RATES, ParamCheck, StreamRequester
from taco_mav.mavlink.stream_watch import StreamWatch
from taco_mav.mavlink.timesync import ClockMap

log = logging.getLogger(__name__)

# Companion s the daemon loop leaves between its reads of the link, unless an output or a heartbeat is due (what
# came in meanwhile is handled at once; outputs read the link first). A pass pays a fixed round (fix results, camera
# speed, schedules) and cold caches: the companion bench's loop took 0.069 core at 63 passes a second (a read at
# every arrival, 20 ms at most), 0.042 at 20, 0.035 at 10 (thread CPU over the mission). On the companion clock, so
# that a simulator's faster clock is read as often in its own time (a recorder at 10 Hz of a 5x simulator kept 79
# frames of 25 s on a wall-clock period); the loop waits in steps of at most WAKE_S wall s, LOOP_PERIOD_S at most.
LOOP_PERIOD_S = 0.1
WAKE_S = 0.02

__all__ = ["AutopilotLink"]

class AutopilotLink:
    """profile: its `link` and `output` sections; clockmap: the autopilot clock, fed here; wants_pose(): whether
    the simulator's true pose is needed (a camera that renders from it, a matcher that answers from it);
    link_timeout_s: silence (companion s) that makes a lost link."""

    def __init__(self, *, profile: Profile, clockmap: ClockMap, reporter: Reporter, link_timeout_s: float,
                 wants_pose: Callable[[], bool]) -> None:
        p = profile
        self.profile, self.clockmap, self.reporter = p, clockmap, reporter
        self.wants_pose = wants_pose
        self.imu_kind: str | None = None if p.link.imu_message == "auto" else p.link.imu_message
        self.link: Link | None = None
        self.linkwatch = LinkWatch(link_timeout_s)
        self.requester: StreamRequester | None = None  # made when the autopilot is adopted (`_request_streams`)
        self.streamwatch: StreamWatch | None = None  # the estimator's inputs arriving at their granted rate: made then
        self.params_check: ParamCheck | None = None  # made when the session opens (link.check_params)
        self.wheel_params: ParamRead | None = None  # WENC_POS_Y, WENC2_POS_Y (wheels.pos_y_from_autopilot): then
        self.t_heartbeat = Periodic(p.link.heartbeat_hz, 0.0)
        self.t_timesync = Periodic(p.link.timesync_hz, 0.0) if p.link.timesync_hz > 0 else None
        self.awaiting_until = -math.inf  # companion s until which our TIMESYNC request's answer is awaited

    def handlers(self) -> dict[str, Callable[[Any, float], None]]:
        return {"SYSTEM_TIME": self._on_system_time, "TIMESYNC": self._on_timesync,
                "COMMAND_ACK": self._on_command_ack, "PARAM_VALUE": self._on_param_value}

    def open(self, link: Link, now: float) -> None:
        """The session's link is up at companion time `now` (s)."""
        p = self.profile
        self.link = link
        self.params_check = ParamCheck(link.send, link.mav, p.output.gps_id, antenna_frd_m=p.output.antenna_frd_m) \
            if p.link.check_params and "gps_input" in p.output.messages else None
        self.wheel_params = ParamRead(link.send, link.mav, WHEEL_POS_PARAMS) \
            if p.wheels.enabled and p.wheels.pos_y_from_autopilot else None
        self.t_heartbeat.restart(now)
        if self.t_timesync is not None:
            self.t_timesync.restart(now)

    def read_period(self, now: float) -> float:
        """Companion s the daemon loop may leave between its reads of the link at companion time `now`: LOOP_PERIOD_S,
        or 0 while our TIMESYNC request's answer is awaited (its handling time is the measurement: read in the
        next batch, the offset read half the wait late, 47 ms at 0.1 s)."""
        return 0.0 if now < self.awaiting_until else LOOP_PERIOD_S

    def wheel_pos_y(self) -> tuple[float, float] | None:
        """The wheels' lateral positions the autopilot reports (WENC_POS_Y, WENC2_POS_Y: body FRD y, metres), None
        until both were read."""
        wp = self.wheel_params
        if wp is None or not wp.complete:
            return None
        return wp.values[WHEEL_POS_PARAMS[0]], wp.values[WHEEL_POS_PARAMS[1]]

    @property
    def next_due(self) -> float:
        """Companion time of our next HEARTBEAT (the loop wakes for it)."""
        return self.t_heartbeat.next_due

    # ------------------------------------------------------------------ messages
    def on_heartbeat(self, msg: Any) -> bool:
        """Any HEARTBEAT: an autopilot's (not a ground station's or another companion's, and the configured sysid
        if one is) may be adopted; True when it comes from the adopted autopilot."""
        link = self.link
        assert link is not None
        if not (msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type not in (MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER)
                and (self.profile.link.target_sysid in (0, msg.get_srcSystem()))):
            return False
        if link.adopt_autopilot(msg):
            self.reporter.event("autopilot", sysid=link.target_system, compid=link.target_component,
                                autopilot=msg.autopilot)
            self._request_streams(msg.autopilot)
        return (msg.get_srcSystem(), msg.get_srcComponent()) == (link.target_system, link.target_component)

    def heard(self, now: float, kind: str = "HEARTBEAT") -> None:
        """A message of type `kind` from our autopilot at companion time `now` (s): ends a link outage (event +
        STATUSTEXT, now that it is reachable) and counts toward its stream's rate."""
        if self.streamwatch is not None:
            self.streamwatch.arrived(kind, now)
        outage = self.linkwatch.heard(now)
        if outage is not None:
            text = f"link restored after {outage:.1f}s"
            log.warning("%s", text)
            self.reporter.event("link_restored", outage_s=outage)
            self.reporter.status(SEV_WARNING, text)

    def _request_streams(self, autopilot: int) -> None:
        """Ask the adopted autopilot (HEARTBEAT.autopilot: MAV_AUTOPILOT_*) for the input streams; a simulator's
        true pose (when `wants_pose`) is SIMSTATE on ArduPilot SITL and HIL_STATE_QUATERNION on PX4 SIH (neither
        is sent unless asked for)."""
        p = self.profile
        if not p.link.request_rates:
            return
        imu = self.imu_kind or IMU_REQUESTED
        # asked for one at a time, in this order: the estimator's inputs first (until granted they come at the
        # port's default 1-4 Hz, and the daemon is DEGRADED)
        rates = {imu: p.link.imu_rate_hz, ATTITUDE_REQUESTED: p.link.attitude_rate_hz, "SYSTEM_TIME": 1.0,
                 "GPS_RAW_INT": 2.0, "VFR_HUD": 5.0,
                 "GLOBAL_POSITION_INT": 2.0}  # the autopilot's own position: where a restarted daemon starts
        if self.wants_pose():
            rates["HIL_STATE_QUATERNION" if autopilot == MAV_AUTOPILOT_PX4 else "SIMSTATE"] = p.link.imu_rate_hz
        if p.wheels.enabled:  # first: ArduPilot refuses its interval, and the fallback sets the rate of its whole
            # stream group (EXTRA1, with ATTITUDE and SIMSTATE), whose own intervals asked for after it then hold
            rates = {"WHEEL_DISTANCE": p.wheels.rate_hz, **rates}
        rates.update(GNSS_RATES)  # GNSS stays read after the origin: it is fused while it is honest
        assert self.link is not None
        self.requester = StreamRequester(self.link.send, self.link.mav, rates)
        self.streamwatch = StreamWatch((imu, ATTITUDE_REQUESTED))

    def _on_system_time(self, msg: Any, received: float) -> None:
        self.clockmap.on_system_time(msg.time_boot_ms)

    def _on_timesync(self, msg: Any, received: float) -> None:
        link = self.link
        assert link is not None
        if msg.tc1 == 0:  # the autopilot asks us: answer with our clock
            link.send(link.mav.timesync_encode(self.clockmap.request_ns(), msg.ts1))
        else:
            self.clockmap.on_timesync_reply(msg.tc1, msg.ts1)
            self.awaiting_until = -math.inf

    def _on_command_ack(self, msg: Any, received: float) -> None:
        if self.requester is not None and self.link is not None:
            self.requester.on_message(msg, self.link.target_system, self.link.target_component)

    def _on_param_value(self, msg: Any, received: float) -> None:
        if self.wheel_params is not None:
            self.wheel_params.on_message(msg)
        if self.params_check is None:
            return
        warning = self.params_check.on_message(msg)
        if warning:  # GPSn_TYPE not 14: an error; an antenna offset unlike the profile's: a warning
            antenna = warning == self.params_check.antenna_warning
            self.reporter.status(SEV_WARNING if antenna else SEV_ERROR, warning)
            extra = ({"autopilot_antenna_m": self.params_check.antenna,
                      "antenna_frd_m": list(self.profile.output.antenna_frd_m)} if antenna else {})
            self.reporter.event("param_check", warning=warning, **extra)

    # ------------------------------------------------------------------ periodic
    def tick(self, now: float) -> None:
        """Our HEARTBEAT, a TIMESYNC request, pending stream requests and parameter reads."""
        link = self.link
        assert link is not None
        if self.t_heartbeat.due(now):
            link.heartbeat()
        if self.t_timesync is not None and link.target_system and self.t_timesync.due(now):
            link.send(link.mav.timesync_encode(0, self.clockmap.request_ns()))
            self.awaiting_until = now + self.clockmap.max_rtt_s
        if self.requester is not None:
            self.requester.tick(now, link.target_system, link.target_component)
            self._watch_streams(now)
        if self.params_check is not None:
            self.params_check.tick(now, link.target_system, link.target_component)
        if self.wheel_params is not None and self.wheel_params.tick(now, link.target_system, link.target_component):
            log.warning("no answer to PARAM_REQUEST_READ %s: the wheels' positions are the profile's "
                        "(wheels.wheel_pos_y_m)", ", ".join(self.wheel_params.missing))

    def _watch_streams(self, now: float) -> None:
        """Ask again for an estimator input that stopped coming at its granted rate (`StreamWatch`)."""
        assert self.requester is not None and self.streamwatch is not None
        for name, measured, granted in self.streamwatch.check(now, self.requester.granted()):
            log.warning("%s arrives at %.1f Hz, granted %.0f Hz: asking for it again", name, measured, granted)
            self.reporter.event("stream_slow", message=name, measured_hz=round(measured, 2), granted_hz=granted)
            self.requester.reask(name)

    def watch(self, now: float) -> None:
        """A lost link: nothing from the autopilot for link_timeout_s (logged and written once per outage)."""
        if self.linkwatch.check(now):
            log.warning("link lost: nothing from the autopilot for %.1f s", self.linkwatch.timeout_s)
            self.reporter.event("link_lost", silent_s=now - (self.linkwatch.last_heard or now))
