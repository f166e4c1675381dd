"""The output stage: one Localiser estimate -> the GPS-style messages the autopilot gets at the output rate
(GPS_INPUT for ArduPilot, HIL_GPS or ODOMETRY for PX4; `output.messages` picks them).

Before encoding, the 1-sigma is grown when the IMU has gone quiet for longer than `output.stall_s` (the vehicle
may be anywhere within speed x age, `health.stall_sigma`), and the health hysteresis (`health.Health`) decides
whether the solution is reported as a 3D fix or degraded; a change of health is handed to `on_change(text,
healthy)` for the log, the event file and a STATUSTEXT. Positions are ENU metres from `origin`, times are
autopilot seconds, the accuracy is metres.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from taco_mav.config import OutputConfig, Profile
from taco_mav.core.types import Estimate
from taco_mav.daemon.health import Health, stall_sigma
from taco_mav.errors import ConfigError
from taco_mav.mavlink import encoders
from taco_mav.mavlink.decoders import AttitudeReading

__all__ = ["GNSS_OUTPUTS", "OUTPUTS", "OutputStage", "writes_gps"]

OUTPUTS = ("gps_input", "hil_gps", "odometry")
GNSS_OUTPUTS = ("gps_input", "hil_gps")  # outputs the autopilot takes as a GPS instance (gps_id + 1)


def writes_gps(output: OutputConfig) -> bool:
    """Whether `output.messages` hold a GPS-instance output (GPS_INPUT, HIL_GPS): then instance gps_id + 1 echoes
    us and is never a receiver."""
    return any(m in GNSS_OUTPUTS for m in output.messages)


class OutputStage:
    """Encodes estimates for `profile.output.messages`; ConfigError when a name there is not in OUTPUTS."""

    def __init__(self, profile: Profile, on_change: Callable[[str, bool], None]) -> None:
        cfg = profile.output
        bad = [m for m in cfg.messages if m not in OUTPUTS]
        if bad or not cfg.messages:
            raise ConfigError(f"output.messages: {bad or '[]'} not in {', '.join(OUTPUTS)}")
        self.cfg = cfg
        self.compass_sigma_rad = profile.ukf.compass_sigma_rad
        self.health = Health(cfg.degrade_accuracy_m, cfg.recover_accuracy_m, cfg.stall_s)
        self._on_change = on_change
        self.writes_gps = writes_gps(cfg)
        self.last_hacc_m: float | None = None  # horizontal 1-sigma of the last solution sent, m (gcs.py: taco_hacc)

    def messages(self, est: Estimate, imu_age_s: float, origin: encoders.Origin, mav: Any, utc_s: float,
                 clock_offset_s: float | None, attitude: AttitudeReading | None,
                 gyro_frd: tuple[float, float, float], reboots: int) -> list[Any]:
        """The messages for `est`. imu_age_s: companion seconds since the last IMU sample; utc_s: UTC unix
        seconds (GPS week/ms); clock_offset_s: autopilot minus companion clock, s (ClockMap.offset; None while
        unknown): ODOMETRY is stamped on the companion clock, the one our TIMESYNC answers carry, which PX4 maps
        onto its own; attitude and gyro_frd (rad/s, body FRD) fill ODOMETRY; reboots: its reset counter."""
        finite = bool(np.all(np.isfinite(est.cov_xy)) and np.all(np.isfinite(est.xy)))
        sigma = est.sigma_h if finite else float("nan")  # a non-finite estimate is reported as such
        if imu_age_s > self.cfg.stall_s and math.isfinite(sigma):
            grown = stall_sigma(sigma, est.speed, imu_age_s)
            est = dataclasses.replace(est, cov_xy=est.cov_xy + (grown**2 - sigma**2) * np.eye(2))
        change = self.health.update(sigma, imu_age_s)
        if change:
            self._on_change(change, self.health.healthy)
        sol = encoders.solution(est, origin, self.cfg, self.health.healthy)
        self.last_hacc_m = min(sol.sigma_h, 1000.0) if math.isfinite(sol.sigma_h) else 1000.0
        out = []
        for name in self.cfg.messages:
            if name == "gps_input":
                out.append(encoders.gps_input(mav, sol, self.cfg, utc_s))
            elif name == "hil_gps":
                out.append(encoders.hil_gps(mav, sol, self.cfg, utc_s))
            else:
                a = attitude
                t_companion = None if clock_offset_s is None else sol.t_autopilot - clock_offset_s
                out.append(encoders.odometry(mav, sol, self.cfg, a.roll if a else 0.0, a.pitch if a else 0.0,
                                             gyro_frd, self.compass_sigma_rad, reboots, t_companion))
        return out
