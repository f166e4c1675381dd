"""The daemon's input side: which messages are acted on (only the adopted autopilot's), and the IMU, attitude,
throttle and simulator-pose handlers.

A mixin of `Daemon` (methods only, annotated `self: Daemon`): the loop thread owns all daemon state, this module
only groups the methods that read messages.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any

from taco_mav.core.types import ImuSample
from taco_mav.daemon.anchor import OriginCandidate
from taco_mav.daemon.imu_source import ATTITUDE_MESSAGES, ATTITUDE_STALE_S
from taco_mav.daemon.imu_timeline import Verdict
from taco_mav.mavlink.decoders import GNSS_MESSAGES, IMU_MESSAGES, ORIGIN_MESSAGES, POSE_MESSAGES
from taco_mav.mavlink.mavconst import (MAV_AUTOPILOT_INVALID, MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER, SEV_ERROR,
                                       SEV_WARNING)

if TYPE_CHECKING:
    from taco_mav.daemon.daemon import Daemon

log = logging.getLogger(__name__)

__all__ = ["DaemonInputs"]


class DaemonInputs:
    """Message dispatch and the IMU / attitude / VFR_HUD / simulator-pose handlers of `Daemon`."""

    def _heard(self: Daemon) -> None:
        """A message from our autopilot: ends a link outage (event + STATUSTEXT, now that it is reachable)."""
        outage = self.linkwatch.heard(self.clock())
        if outage is not None:
            text = f"link restored after {outage:.1f}s"
            log.warning("%s", text)
            self.events.write("link_restored", outage_s=outage)
            self._status(SEV_WARNING, text, key=None)

    def _handle(self: Daemon, msg: Any, received: float) -> None:
        """One decoded message: a HEARTBEAT may adopt the autopilot; anything else is acted on only when it comes
        from the adopted autopilot. received: perf_counter seconds at receipt (IMU-to-estimate latency)."""
        kind = msg.get_type()
        link = self.link
        assert link is not None
        if kind == "HEARTBEAT":
            if (msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type not in (MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER)
                    and (self.profile.link.target_sysid in (0, msg.get_srcSystem()))):
                if link.adopt_autopilot(msg):
                    self.events.write("autopilot", sysid=link.target_system, compid=link.target_component,
                                      autopilot=msg.autopilot)
                    self._request_streams(msg.autopilot)
                if (msg.get_srcSystem(), msg.get_srcComponent()) == (link.target_system, link.target_component):
                    self._heard()
                    self.drive.on_heartbeat(msg)
            return
        if not link.target_system:
            self.decoders.reject(kind, "before_autopilot")
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (link.target_system, link.target_component):
            self.decoders.reject(kind, "foreign_source")  # only the adopted autopilot's messages are acted on
            return
        self._heard()
        if kind in IMU_MESSAGES:
            self._on_imu(msg, received)
        elif kind in ATTITUDE_MESSAGES:
            self.attitude = self.sources.attitude_reading(msg, self.decoders, self.clock()) or self.attitude
            self._source_switches()
        elif kind in GNSS_MESSAGES:
            self._on_gnss(msg)
        elif kind in ORIGIN_MESSAGES:
            o = self.decoders.origin(msg) if self.origin is None else None
            if o is not None:
                self._offer_origin(OriginCandidate(o.lat, o.lon, o.alt, 0.0, None, o.source))
        elif kind == "SYSTEM_TIME":
            self.clockmap.on_system_time(msg.time_boot_ms)
        elif kind == "TIMESYNC":
            if msg.tc1 == 0:  # the autopilot asks us: answer with our clock
                link.send(link.mav.timesync_encode(self.clockmap.request_ns(), msg.ts1))
            else:
                self.clockmap.on_timesync_reply(msg.tc1, msg.ts1)
        elif kind in POSE_MESSAGES:
            self._on_sim_pose(msg)
        elif kind == "VFR_HUD":
            self._on_vfr_hud(msg)
        elif kind == "COMMAND_ACK" and self.requester is not None:
            self.requester.on_message(msg, link.target_system, link.target_component)
        elif kind == "PARAM_VALUE" and self.params_check is not None:
            warning = self.params_check.on_message(msg)
            if warning:  # GPSn_TYPE not 14: an error; an antenna offset unlike the profile's: a warning
                antenna = warning == self.params_check.antenna_warning
                self._status(SEV_WARNING if antenna else SEV_ERROR, warning, key=None)
                extra = ({"autopilot_antenna_m": self.params_check.antenna,
                          "antenna_frd_m": list(self.profile.output.antenna_frd_m)} if antenna else {})
                self.events.write("param_check", warning=warning, **extra)

    def _on_imu(self: Daemon, msg: Any, received: float) -> None:
        """An IMU message: the chosen stream's valid sample, checked against the autopilot timeline (reboots, gaps,
        outliers), with the attitude at its time, into the Localiser (anchored at the first one after the origin)."""
        r = self.sources.imu_reading(msg, self.decoders, self.clock())  # the chosen stream's valid samples only
        self._source_switches()
        if r is None:
            return
        check = self.timeline.check(r.t, self.loc is not None)
        if check.outlier:
            self.stats.dropped["imu_time_outlier"] += 1
        if check.verdict in (Verdict.UNCONFIRMED, Verdict.OUT_OF_ORDER):
            self.stats.dropped[check.verdict.value] += 1
            return
        if check.verdict is Verdict.REBOOT:
            self._reboot(check.t_from, check.t_to)
        elif check.verdict is Verdict.GAP:
            self._imu_gap(check.t_from, check.t_to)
        self.clockmap.on_autopilot_time(r.t)
        self.last_imu = r
        self._last_imu_clock = self.clock()
        if self.attitude is None:
            self.stats.dropped["imu_before_attitude"] += 1
            return
        a = self.attitude.at(r.t)
        if r.t - self.attitude.t > ATTITUDE_STALE_S:  # no valid attitude for a while: the last one is used
            self.stats.attitude_stale += 1
            self._status(SEV_WARNING, f"attitude stale {r.t - self.attitude.t:.1f}s", key="attitude_stale")
        if self.loc is None:
            if self.origin is None:
                self.stats.dropped["imu_before_origin"] += 1
                return
            self.loc = self.anchor.localiser(r.t, a.yaw)
        assert self.loc is not None
        self.loc.add_imu(ImuSample(r.t, r.accel_frd, r.gyro_frd, a.roll, a.pitch, a.yaw))
        self.stats.imu_samples += 1
        self.stats.imu_to_estimate_s.append(time.perf_counter() - received)

    def _source_switches(self: Daemon) -> None:
        """Log, count (summary "sources") and write the IMU / attitude source chosen or changed; a fallback
        also goes to the ground station."""
        for what, sw in self.sources.take_switches():
            self.events.write("input_source", input=what, old=sw.old, new=sw.new, silent_s=sw.silent_s)
            if sw.old is None:
                log.info("%s input: %s", what.upper() if what == "imu" else what, sw.new)
                continue
            text = f"{what} {sw.old} silent {sw.silent_s:.1f}s: using {sw.new}"
            log.warning("%s", text)
            self._status(SEV_WARNING, text, key=None)

    def _on_vfr_hud(self: Daemon, msg: Any) -> None:
        """The autopilot's throttle output (%): whether it drives (`drive.DriveCommand`) vetoes taco+'s
        zero-velocity updates (a smooth cruise looks still to the IMU, issue 19)."""
        throttle = getattr(msg, "throttle", None)
        if not isinstance(throttle, int) or not -100 <= throttle <= 100:
            self.decoders.reject("VFR_HUD", "range")
            return
        driving = self.drive.driving(throttle)
        set_drive = getattr(self.loc, "set_drive_command", None)
        if set_drive is not None and self.last_imu is not None and driving is not None:
            set_drive(self.last_imu.t, driving)

    def _on_sim_pose(self: Daemon, msg: Any) -> None:
        """A simulator's true pose (SIMSTATE, HIL_STATE_QUATERNION): to the fix pipeline (world camera, emulator
        matcher)."""
        pose = self.decoders.sim_pose(msg)
        if pose is None or self.last_imu is None:
            return
        self.fixes.on_pose(self.last_imu.t, pose, self.origin)
