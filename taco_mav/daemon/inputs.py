"""The daemon's handler of what the vehicle senses: IMU samples (checked against the autopilot's timeline for
reboots, gaps and outliers) into the Localiser, attitude, the throttle output (whether the autopilot drives), the
wheel encoders (wheels.py, when the profile has them), and a simulator's true pose for the fix pipeline's camera
and the true-pose track. It anchors the Localiser at
the first IMU sample after the origin, and again after a reboot or a gap."""

from __future__ import annotations

import logging
import time
from typing import Any, Callable

from taco_mav.config import Profile
from taco_mav.core.types import ImuSample
from taco_mav.daemon.drive import DriveCommand
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.imu_source import ATTITUDE_MESSAGES, ATTITUDE_STALE_S, InputSources
from taco_mav.daemon.imu_timeline import ImuTimeline, TimelineVerdict
from taco_mav.daemon.options import DaemonStats
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.state import LiveState
from taco_mav.daemon.true_pose import TruePoseTrack
from taco_mav.daemon.wheels import WheelInput
from taco_mav.mavlink.decoders import IMU_MESSAGES, POSE_MESSAGES, Decoders
from taco_mav.mavlink.mavconst import SEV_WARNING
from taco_mav.mavlink.timesync import ClockMap

log = logging.getLogger(__name__)

__all__ = ["Inputs"]


class Inputs:
    """state: shared with the other handlers (this one writes attitude, last_imu and the Localiser);
    clock: companion monotonic seconds; decoders: field checks and rejection counters; fixes: its camera takes
    the simulator's true pose; truth: the true-pose track of a matcher that answers from it (None: none does);
    wheel_pos_y: the wheels' lateral positions as the autopilot reports them (None until read)."""

    def __init__(self, *, profile: Profile, state: LiveState, stats: DaemonStats, decoders: Decoders,
                 clockmap: ClockMap, fixes: FixPipeline, reporter: Reporter, clock: Callable[[], float],
                 truth: TruePoseTrack | None,
                 wheel_pos_y: Callable[[], tuple[float, float] | None] = lambda: None) -> None:
        self.state, self.stats, self.decoders = state, stats, decoders
        self.clockmap, self.fixes, self.reporter, self.clock = clockmap, fixes, reporter, clock
        self.truth = truth
        self.sources = InputSources(profile.link.imu_message)  # IMU and attitude streams: first valid, fallback
        self.timeline = ImuTimeline(profile.link.reboot_backstep_s, profile.imu.max_dt_s)
        self.drive = DriveCommand()  # armed / driving, from the autopilot's HEARTBEAT and VFR_HUD
        self.wheels = WheelInput(profile=profile, state=state, decoders=decoders, reporter=reporter,
                                 pos_y=wheel_pos_y)

    def handlers(self) -> dict[str, Callable[[Any, float], None]]:
        out: dict[str, Callable[[Any, float], None]] = {k: self.on_imu for k in IMU_MESSAGES}
        out.update({k: self.on_attitude for k in ATTITUDE_MESSAGES})
        out.update({k: self.on_sim_pose for k in POSE_MESSAGES})
        out["VFR_HUD"] = self.on_vfr_hud
        out.update(self.wheels.handlers())
        return out

    def on_heartbeat(self, msg: Any) -> None:
        """The adopted autopilot's HEARTBEAT: armed and mode, for the drive command."""
        self.drive.on_heartbeat(msg)

    # ------------------------------------------------------------------ messages
    def on_imu(self, msg: Any, received: float) -> None:
        """An IMU message: the chosen stream's valid sample, checked against the autopilot timeline (reboots, gaps,
        outliers), with the attitude at its time, into the Localiser (anchored at the first one after the origin).
        received: perf_counter seconds at receipt (IMU-to-estimate latency)."""
        st = self.state
        r = self.sources.imu_reading(msg, self.decoders, self.clock())  # the chosen stream's valid samples only
        self._source_switches()
        if r is None:
            return
        check = self.timeline.check(r.t, st.loc is not None)
        if check.outlier:
            self.stats.dropped["imu_time_outlier"] += 1
        if check.verdict in (TimelineVerdict.UNCONFIRMED, TimelineVerdict.OUT_OF_ORDER):
            self.stats.dropped[check.verdict.value] += 1
            return
        if check.verdict is TimelineVerdict.REBOOT:
            self._reboot(check.t_from, check.t_to)
        elif check.verdict is TimelineVerdict.GAP:
            self._imu_gap(check.t_from, check.t_to)
        self.clockmap.on_autopilot_time(r.t)
        st.last_imu = r
        st.last_imu_clock = self.clock()
        self.wheels.watch(st.last_imu_clock)
        if st.attitude is None:
            self.stats.dropped["imu_before_attitude"] += 1
            return
        a = st.attitude.at(r.t)
        if r.t - st.attitude.t > ATTITUDE_STALE_S:  # no valid attitude for a while: the last one is used
            self.stats.attitude_stale += 1
            self.reporter.status(SEV_WARNING, f"attitude stale {r.t - st.attitude.t:.1f}s", key="attitude_stale")
        if st.loc is None:
            if st.origin is None:
                self.stats.dropped["imu_before_origin"] += 1
                return
            if st.anchor.holding(self.clock()):  # waiting for the autopilot's position (a restart)
                self.stats.dropped["imu_before_start"] += 1
                return
            st.loc = st.anchor.localiser(r.t, a.yaw)
            self._anchored()
        sample = ImuSample(r.t, r.accel_frd, r.gyro_frd, a.roll, a.pitch, a.yaw)
        st.loc.add_imu(sample)
        if st.twin is not None:
            st.twin.add_imu(sample)
        self.stats.imu_samples += 1
        self.stats.imu_to_estimate_s.append(time.perf_counter() - received)

    def on_attitude(self, msg: Any, received: float) -> None:
        """ATTITUDE / ATTITUDE_QUATERNION: the chosen stream's valid reading."""
        self.state.attitude = self.sources.attitude_reading(msg, self.decoders, self.clock()) or self.state.attitude
        self._source_switches()

    def on_vfr_hud(self, msg: Any, received: float) -> None:
        """The autopilot's throttle output (%): whether it drives (`drive.DriveCommand`) vetoes taco+'s
        zero-velocity updates (a smooth cruise looks still to the IMU)."""
        throttle = getattr(msg, "throttle", None)
        if not isinstance(throttle, int) or not -100 <= throttle <= 100:
            self.decoders.reject("VFR_HUD", "range")
            return
        driving = self.drive.driving(throttle)
        loc, last = self.state.loc, self.state.last_imu
        if loc is not None and last is not None and driving is not None:
            loc.set_drive_command(last.t, driving)
            if self.state.twin is not None:
                self.state.twin.set_drive_command(last.t, driving)

    def on_sim_pose(self, msg: Any, received: float) -> None:
        """A simulator's true pose (SIMSTATE, HIL_STATE_QUATERNION) at the latest IMU time: to the fix pipeline's
        camera (a world camera renders from it) and, once there is an origin, to the true-pose track."""
        st = self.state
        pose = self.decoders.sim_pose(msg)
        if pose is None or st.last_imu is None:
            return
        self.fixes.on_pose(st.last_imu.t, pose)
        if self.truth is not None and st.origin is not None:
            self.truth.add(st.last_imu.t, pose, st.origin)

    # ------------------------------------------------------------------ re-anchoring
    def _reboot(self, t_last: float, t_new: float) -> None:
        """Autopilot clock went back: re-anchor at the current estimate on the new clock."""
        st = self.state
        self.stats.reboots += 1
        text = f"autopilot reboot? time {t_last:.1f}s -> {t_new:.1f}s: re-anchored"
        log.warning("%s", text)
        self.reporter.event("reboot", t_last=t_last, t_new=t_new)
        self.reporter.status(SEV_WARNING, text, key="reboot")
        self.clockmap.reset()
        if self.truth is not None:
            self.truth.clear()
        if st.loc is not None and st.attitude is not None:
            st.loc = st.anchor.restarted(st.loc, st.attitude.yaw, t_new)
            self._anchored()
        st.last_imu = None

    def _imu_gap(self, t_last: float, t_new: float) -> None:
        """No IMU from t_last to t_new (autopilot s), longer than the preintegrator bridges (imu.max_dt_s): the
        motion in between is unknown. Re-anchor at the estimate carried on at its speed and heading, with the
        1-sigma grown over the gap, so the output stays degraded until fixes bring it back."""
        st = self.state
        assert st.loc is not None and st.attitude is not None
        c = st.anchor.carried(st.loc, t_last, t_new)
        self.stats.imu_gaps += 1
        log.warning("IMU gap %.1f s: re-anchored %.1f m ahead, sigma %.1f m", t_new - t_last, abs(c.carried_m), c.sigma)
        self.reporter.event("imu_gap", t_last=t_last, t_new=t_new, sigma_h=c.sigma, carried_m=c.carried_m)
        st.loc = st.anchor.localiser(t_new, st.attitude.yaw, c.xy, c.heading, c.speed, c.sigma)
        self._anchored()

    def _anchored(self) -> None:
        """A new Localiser: the shadow twin (--shadow) starts beside it, from the same state."""
        if self.state.shadow is not None:
            self.state.shadow.anchored(self.state.anchor.twin())

    def _source_switches(self) -> None:
        """Log, count (summary "sources") and write the IMU / attitude source chosen or changed; a fallback
        also goes to the ground station."""
        for what, sw in self.sources.take_switches():
            self.reporter.event("input_source", input=what, old=sw.old, new=sw.new, silent_s=sw.silent_s)
            if sw.old is None:
                log.info("%s input: %s", what.upper() if what == "imu" else what, sw.new)
                continue
            text = f"{what} {sw.old} silent {sw.silent_s:.1f}s: using {sw.new}"
            log.warning("%s", text)
            self.reporter.status(SEV_WARNING, text)
