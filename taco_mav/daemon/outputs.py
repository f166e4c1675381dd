"""The daemon's handler of what goes out: the position messages of each output slot (GPS_INPUT, HIL_GPS,
ODOMETRY at output.rate_hz in autopilot time), their health (fix type, with a log line, an event and a
STATUSTEXT at each change), the ground station's NAMED_VALUE_FLOAT health at 1 Hz, and the periodic stats
line of the event log."""

from __future__ import annotations

import logging
from typing import Any, Callable

from taco_mav.config import Profile
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.daemon.gcs import GCS_HEALTH_HZ, GcsHealth
from taco_mav.daemon.gnss import GnssTracker
from taco_mav.daemon.options import DaemonStats
from taco_mav.daemon.output_stage import OutputStage
from taco_mav.daemon.reporter import Reporter
from taco_mav.daemon.scheduler import AutopilotPeriodic, Periodic
from taco_mav.daemon.state import LiveState
from taco_mav.mavlink import encoders
from taco_mav.mavlink.connection import Link
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_WARNING
from taco_mav.mavlink.timesync import ClockMap

log = logging.getLogger(__name__)

__all__ = ["Outputs"]

STATS_INTERVAL_S = 10.0  # the event log's "stats" line


class Outputs:
    """state: shared (read here); wall_clock: UTC unix seconds (GPS week and ms); gnss: the real GNSS as the
    origin handler tracks it (the ground station's GNSS line); summary(): the daemon's counters (the stats
    line)."""

    def __init__(self, *, profile: Profile, state: LiveState, stats: DaemonStats, clockmap: ClockMap,
                 fixes: FixPipeline, reporter: Reporter, wall_clock: Callable[[], float], gnss: GnssTracker,
                 summary: Callable[[], dict[str, Any]]) -> None:
        self.state, self.stats, self.clockmap, self.fixes, self.reporter = state, stats, clockmap, fixes, reporter
        self.wall_clock, self.gnss, self.summary = wall_clock, gnss, summary
        self.stage = OutputStage(profile, self._health_changed)
        self.gcs = GcsHealth()
        self.link: Link | None = None
        self.t_output = AutopilotPeriodic(profile.output.rate_hz, 0.0, clockmap.speed)  # rate in autopilot time
        self.t_gcs = AutopilotPeriodic(GCS_HEALTH_HZ, 0.0, clockmap.speed)  # NAMED_VALUE_FLOAT health
        self.t_stats = Periodic(1.0 / STATS_INTERVAL_S, STATS_INTERVAL_S)

    def open(self, link: Link, now: float) -> None:
        """The session's link is up at companion time `now` (s): the schedules start."""
        self.link = link
        self.t_output.restart(now)
        self.t_gcs.restart(now)
        self.t_stats.restart(now + STATS_INTERVAL_S)

    @property
    def next_due(self) -> float:
        """Companion time of the next output slot (the loop wakes for it)."""
        return self.t_output.next_due

    def tick(self, now: float) -> None:
        """The output slot when due."""
        if self.t_output.due(now):
            self._send(now)

    def tick_reports(self, now: float) -> None:
        """The ground station's health when due (on its grid from the start, sent once there is a target), and
        the stats line."""
        assert self.link is not None
        if self.t_gcs.due(now) and self.link.target_system:
            self._gcs_health(now)
        if self.t_stats.due(now):
            self.reporter.event("stats", **self.summary())

    def _send(self, now: float) -> None:
        """The position messages of this output slot (none before the origin and the Localiser)."""
        st, link = self.state, self.link
        if st.loc is None or st.origin is None or link is None:
            return
        gyro = st.last_imu.gyro_frd if st.last_imu else (0.0, 0.0, 0.0)
        for msg in self.stage.messages(st.loc.estimate(), now - st.last_imu_clock, st.origin, link.mav,
                                       self.wall_clock(), self.clockmap.offset, st.attitude, gyro, self.stats.reboots):
            link.send(msg)
        self.stats.output_times.append(now)

    def _gcs_health(self, now: float) -> None:
        """NAMED_VALUE_FLOAT health for the ground station; a change of mode: log, event and STATUSTEXT."""
        link, st = self.link, self.state
        assert link is not None
        svc = self.fixes.service.stats if self.fixes.service is not None else None
        rep = self.gcs.update(now, st.loc.estimate() if st.loc is not None and st.origin is not None else None,
                              self.stage.last_hacc_m, self.stage.health.healthy,
                              "rejected" if self.gnss.rejecting else self.gnss.state, self.stats.fixes,
                              svc.answered if svc else 0, svc.triggers_off_map if svc else 0, self.fixes.last_weight)
        t_ap = self.clockmap.now_autopilot()
        for name, value in rep.values:
            link.send(encoders.named_value_float(link.mav, int(t_ap * 1e3) if t_ap else 0, name, value))
        if rep.change is not None:
            severity, text = rep.change
            log.warning("%s", text) if severity <= SEV_WARNING else log.info("%s", text)
            self.reporter.event("mode", mode=self.gcs.mode.name, code=int(self.gcs.mode), text=text)
            self.reporter.status(severity, text)

    def _health_changed(self, text: str, healthy: bool) -> None:
        """The output's health changed (fix type degraded or restored): log, event and STATUSTEXT."""
        log.info("%s", text) if healthy else log.warning("%s", text)
        self.reporter.event("health", text=text, healthy=healthy)
        self.reporter.status(SEV_INFO if healthy else SEV_WARNING, text)
