"""Loss-of-lock detection and recovery for taco+ (not in the paper).

States: LOCKED (normal fixes), LOST (the estimate may be further off than the capture radius: search a
hexagonal grid sized by the inflated uncertainty), CONFIRMING (a relocalisation was applied; its jump stays
in the reported uncertainty until `confirm_fixes` further fixes agree).

Lock is declared lost after `lost_after` consecutive answered triggers without an accepted fix (misses, gate
rejections, innovation rejections alike) whose run spans at least `lost_after_s` seconds from its first failure
(a short run of confident, mutually consistent outliers must not outvote a good IMU, however long ago the last
fix was), or when the filter's 1-sigma exceeds a third of the capture radius (3 sigma no longer fits inside
one crop's capture). Events are kept as (t, kind, detail) for logs and counts.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field


class LockState(enum.Enum):
    LOCKED = "locked"
    LOST = "lost"
    CONFIRMING = "confirming"


@dataclass
class LockMonitor:
    """Counts consecutive failed triggers and moves between the lock states. Times in seconds; lengths in
    metres."""

    lost_after: int
    lost_after_s: float
    capture_radius_m: float
    confirm_fixes: int
    last_accept_t: float = 0.0
    state: LockState = LockState.LOCKED
    misses: int = 0
    first_miss_t: float = 0.0  # time of the first failure of the current run
    attempts: int = 0  # failed recovery attempts since lock was lost
    confirmations: int = 0
    jump_m: float = 0.0
    losses: int = 0
    recoveries: int = 0
    events: list[tuple[float, str, str]] = field(default_factory=list)
    unreported: list[tuple[float, str, str]] = field(default_factory=list)

    def note(self, t: float, kind: str, detail: str) -> None:
        """Record an event of the Localiser's own (the safety guard's) beside the lock events."""
        self._event(t, kind, detail)

    def _event(self, t: float, kind: str, detail: str) -> None:
        for store in (self.events, self.unreported):
            store.append((t, kind, detail))
            if len(store) > 1000:  # bounded for the daemon; counts are kept separately
                del store[:500]

    def take_unreported(self) -> list[tuple[float, str, str]]:
        """The events since the last call (for a live log), oldest first."""
        out, self.unreported = self.unreported, []
        return out

    def on_failure(self, t: float, reason: str) -> bool:
        """A trigger produced no accepted fix. Returns True when this declares lock lost."""
        if self.misses == 0:
            self.first_miss_t = t
        self.misses += 1
        if self.state is LockState.LOST:
            self.attempts += 1
            return False
        if self.state is LockState.CONFIRMING:
            self.state, self.confirmations = LockState.LOST, 0
            self._event(t, "relock_failed", reason)
            return False
        if (self.state is LockState.LOCKED and self.misses >= self.lost_after
                and t - self.first_miss_t >= self.lost_after_s):
            return self.declare_lost(t, f"{self.misses} triggers without a fix (last: {reason})")
        return False

    def on_uncertainty(self, t: float, sigma_h: float) -> bool:
        """Check the filter's 1-sigma (metres) against the capture radius; True when this declares lock lost."""
        if self.state is LockState.LOCKED and 3.0 * sigma_h > self.capture_radius_m:
            return self.declare_lost(t, f"3 sigma {3.0 * sigma_h:.1f} m exceeds the capture radius")
        return False

    def declare_lost(self, t: float, detail: str) -> bool:
        self.state, self.confirmations, self.attempts = LockState.LOST, 0, 0
        self.losses += 1
        self._event(t, "lock_lost", detail)
        return True

    def on_relocalised(self, t: float, jump_m: float) -> None:
        """A recovery candidate was applied (the estimate moved by jump_m)."""
        self.state, self.confirmations, self.jump_m, self.misses = LockState.CONFIRMING, 0, jump_m, 0
        self.last_accept_t = t
        self._event(t, "relocalised", f"jump {jump_m:.1f} m")
        if self.confirm_fixes <= 0:
            self._locked(t)

    def on_accepted(self, t: float) -> None:
        """A fix passed every gate."""
        self.misses, self.last_accept_t = 0, t
        if self.state is LockState.CONFIRMING:
            self.confirmations += 1
            if self.confirmations >= self.confirm_fixes:
                self._locked(t)

    def _locked(self, t: float) -> None:
        self.state, self.jump_m = LockState.LOCKED, 0.0
        self.recoveries += 1
        self._event(t, "recovered", "")
