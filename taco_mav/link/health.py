"""Output health: fix_type 3 while the estimate is trustworthy, 1 (no fix) when the 1-sigma horizontal accuracy
exceeds `degrade_accuracy_m` (until it is back under `recover_accuracy_m`) or when no IMU sample has arrived for
`stall_s` seconds. `update` returns the transition text ("degraded: ..." / "recovered") when the state flips."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Health:
    degrade_accuracy_m: float
    recover_accuracy_m: float
    stall_s: float
    healthy: bool = True
    reason: str = ""

    def update(self, sigma_h: float, imu_age_s: float) -> str | None:
        """sigma_h: metres; imu_age_s: seconds since the last IMU sample (companion clock)."""
        if not math.isfinite(sigma_h):
            reason = "estimate not finite"
        elif imu_age_s > self.stall_s:
            reason = f"IMU stalled {imu_age_s:.1f}s"
        elif sigma_h > self.degrade_accuracy_m or (not self.healthy and sigma_h > self.recover_accuracy_m
                                                   and self.reason.startswith("accuracy")):
            reason = f"accuracy {sigma_h:.1f}m"
        else:
            reason = ""
        was = self.healthy
        self.healthy, self.reason = not reason, reason
        if was and reason:
            return f"degraded: {reason}"
        if not was and not reason:
            return f"recovered: sigma {sigma_h:.1f}m"
        return None
