"""Output health: fix_type 3 while the estimate is trustworthy, 1 (no fix) when the 1-sigma horizontal accuracy
exceeds `degrade_accuracy_m` (until it is back under `recover_accuracy_m`) or when no IMU sample has arrived for
`stall_s` seconds. `update` returns the transition text ("degraded: ..." / "recovered") when the state flips.

`LinkWatch` tells when the autopilot has gone silent (link lost: cable, radio, TCP peer gone, autopilot hung)
and when it is heard again; `stall_sigma` inflates the reported accuracy while no IMU arrives, so the 1-sigma
sent with fix_type 1 still covers how far the vehicle may have gone."""

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


def stall_sigma(sigma_h: float, speed: float, silent_s: float, speed_margin: float = 1.0) -> float:
    """1-sigma horizontal accuracy, m, after silent_s seconds without IMU: sigma_h (m) and half of
    (|speed| + speed_margin) m/s x silent_s added in quadrature. With the estimate carried on at `speed`, a
    vehicle that stopped at once, or sped up by speed_margin m/s over the silence, is 2 sigma away."""
    extra = 0.5 * (abs(speed) + speed_margin) * max(0.0, silent_s) if math.isfinite(speed) else math.inf
    return math.hypot(sigma_h, extra)


@dataclass
class LinkWatch:
    """Autopilot link liveness: lost after `timeout_s` seconds (companion clock) without a message from the
    autopilot; restored at the next one. `check(now)` returns True once when the link is declared lost;
    `heard(now)` returns the outage length, s, once when a message ends an outage (None otherwise)."""

    timeout_s: float
    last_heard: float | None = None
    lost_since: float | None = None
    outages: int = 0

    def heard(self, now: float) -> float | None:
        """A message from the autopilot arrived at `now` (s)."""
        ended = None
        if self.lost_since is not None and self.last_heard is not None:
            ended = now - self.last_heard
            self.lost_since = None
        self.last_heard = now
        return ended

    def check(self, now: float) -> bool:
        """True exactly once per outage, when the silence first exceeds timeout_s."""
        if self.last_heard is None or self.lost_since is not None or now - self.last_heard <= self.timeout_s:
            return False
        self.lost_since = now
        self.outages += 1
        return True

    @property
    def lost(self) -> bool:
        return self.lost_since is not None
