"""The daemon's output side: position messages to the autopilot, ground-station health, STATUSTEXT, and the
counters of `Daemon.summary`.

A mixin of `Daemon` (methods only, annotated `self: Daemon`): the loop thread owns all daemon state.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from taco_mav.mavlink import encoders
from taco_mav.mavlink.mavconst import SEV_INFO, SEV_WARNING

if TYPE_CHECKING:
    from taco_mav.daemon.daemon import Daemon

log = logging.getLogger(__name__)

__all__ = ["DaemonOutputs"]


class DaemonOutputs:
    """Outputs, health reports and counters of `Daemon`."""

    def _send_outputs(self: Daemon, now: float) -> None:
        """The position messages of this output slot (none before the origin and the Localiser)."""
        if self.loc is None or self.origin is None or self.link is None:
            return
        gyro = self.last_imu.gyro_frd if self.last_imu else (0.0, 0.0, 0.0)
        for msg in self.output.messages(self.loc.estimate(), now - self._last_imu_clock, self.origin, self.link.mav,
                                        self.wall_clock(), self.clockmap.offset, self.attitude, gyro,
                                        self.stats.reboots):
            self.link.send(msg)
        self.stats.output_times.append(now)

    def _gcs_health(self: Daemon, now: float) -> None:
        """NAMED_VALUE_FLOAT health for the ground station; a change of mode: log, event and STATUSTEXT."""
        link = self.link
        assert link is not None
        svc = self.fixes.service.stats if self.fixes.service is not None else None
        gnss = self.gnss.summary()
        rep = self.gcs.update(now, self.loc.estimate() if self.loc is not None and self.origin is not None else None,
                              self.output.last_hacc_m, self.output.health.healthy,
                              "rejected" if gnss["rejecting"] else gnss["state"], self.stats.fixes,
                              svc.answered if svc else 0, svc.triggers_off_map if svc else 0, self.fixes.last_weight)
        t_ap = self.clockmap.now_autopilot()
        for name, value in rep.values:
            link.send(encoders.named_value_float(link.mav, int(t_ap * 1e3) if t_ap else 0, name, value))
        if rep.change is not None:
            severity, text = rep.change
            log.warning("%s", text) if severity <= SEV_WARNING else log.info("%s", text)
            self.events.write("mode", mode=self.gcs.mode.name, code=int(self.gcs.mode), text=text)
            self._status(severity, text, key=None)

    def _health_changed(self: Daemon, text: str, healthy: bool) -> None:
        """The output's health changed (fix type degraded or restored): log, event and STATUSTEXT."""
        log.info("%s", text) if healthy else log.warning("%s", text)
        self.events.write("health", text=text, healthy=healthy)
        self._status(SEV_INFO if healthy else SEV_WARNING, text, key=None)

    def _status(self: Daemon, severity: int, text: str, key: str | None) -> None:
        """STATUSTEXT to the autopilot (and the log); `key` rate-limits by output.statustext_interval_s."""
        now = self.clock()
        if key is not None:
            if now - self._last_status.get(key, -math.inf) < self.profile.output.statustext_interval_s:
                return
            self._last_status[key] = now
        log.info("STATUSTEXT: %s", text)
        if self.link is not None:
            self.link.send(encoders.statustext(self.link.mav, severity, text))

    def summary(self: Daemon) -> dict[str, Any]:
        """Counters for logs and tests; output_slots_skipped: output periods missed because the loop ran late
        (a stalled machine; each one is a GPS_INPUT the autopilot did not get)."""
        lat = np.array(self.stats.imu_to_estimate_s) * 1e3
        return {"imu_samples": self.stats.imu_samples, "queries": self.stats.queries, "fixes": dict(self.stats.fixes),
                "dropped": dict(self.stats.dropped), "rejected_inputs": dict(self.decoders.rejected),
                "outputs": len(self.stats.output_times),
                "output_slots_skipped": self.t_output.skipped if hasattr(self, "t_output") else 0,
                "reboots": self.stats.reboots, "imu_gaps": self.stats.imu_gaps,
                "sources": self.sources.summary(), "attitude_stale": self.stats.attitude_stale,
                "link_outages": self.linkwatch.outages, "link_lost": self.linkwatch.lost,
                "crops_off_map": self.fixes.service.stats.crops_off_map if self.fixes.service else 0,
                "mode": self.gcs.mode.name if hasattr(self, "gcs") else None,
                "camera_motion": dict(self.motion.counts) if self.motion is not None else None,
                "stuck_matchers": self.fixes.stuck,
                "imu_to_estimate_p99_ms": float(np.percentile(lat, 99)) if len(lat) else None,
                "clock_source": self.clockmap.source, "clock_speed": self.clockmap.speed(),
                "healthy": self.output.health.healthy,
                "sent": self.link.sent if self.link else 0, "received": self.link.received if self.link else 0,
                "estimator": self._estimator_state()}

    def _estimator_state(self: Daemon) -> dict[str, Any] | None:
        """The estimate's 1-sigma (m) and the mode's internal state (taco+: lock, speed error m/s, accelerometer
        bias m/s^2, compass bias rad, fix-noise scale) for the periodic stats line; non-finite values as None."""
        if self.loc is None:
            return None
        est = self.loc.estimate()
        state = {"mode": self.profile.estimator.value, "sigma_h_m": est.sigma_h, **est.extra}
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in state.items()}
