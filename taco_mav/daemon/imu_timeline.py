"""IMU timestamp checks for the daemon: which samples continue the autopilot's timeline, which start a new one
(an autopilot reboot: time steps back; an IMU gap: time jumps forward past what the preintegrator bridges),
and which are corrupt.

A jump is believed only when the next sample continues the new timeline: one corrupt timestamp must not
re-anchor the estimator, so the first sample after a jump is held; the next one confirms the jump (both
report it) or shows it was an outlier (the held sample is dropped). Times are autopilot seconds.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class TimelineVerdict(enum.Enum):
    OK = "ok"  # continues the timeline: integrate it
    OUT_OF_ORDER = "imu_out_of_order"  # not newer than the last sample: drop
    UNCONFIRMED = "imu_time_jump_unconfirmed"  # a jump, held until the next sample: drop for now
    REBOOT = "reboot"  # confirmed step back: re-anchor on the new clock, then integrate
    GAP = "gap"  # confirmed forward jump: re-anchor across the gap, then integrate


@dataclass(frozen=True)
class Check:
    """verdict; t_from / t_to: the last sample before the jump and the first after it (REBOOT, GAP);
    outlier: a held jump turned out to be a lone corrupt sample (count it)."""

    verdict: TimelineVerdict
    t_from: float = 0.0
    t_to: float = 0.0
    outlier: bool = False


class ImuTimeline:
    """backstep_s: a step back longer than this is a reboot; max_dt_s: a step forward longer than this is a gap
    (only once the estimator runs: `anchored`)."""

    def __init__(self, backstep_s: float, max_dt_s: float) -> None:
        self.backstep_s, self.max_dt_s = backstep_s, max_dt_s
        self.last: float | None = None  # the last accepted sample time
        self._held: float | None = None

    def reset(self) -> None:
        """Forget the timeline (after a reboot was handled)."""
        self.last, self._held = None, None

    def check(self, t: float, anchored: bool) -> Check:
        """Classify the sample at time t; OK, REBOOT and GAP also accept it as the new last sample."""
        last = self.last
        back = last is not None and t < last - self.backstep_s
        gap = last is not None and anchored and t - last > self.max_dt_s
        outlier = False
        if back or gap:
            held, self._held = self._held, t
            if held is None or not 0.0 < t - held <= self.max_dt_s:
                return Check(TimelineVerdict.UNCONFIRMED)
            self._held = None
            assert last is not None
            self.last = t
            return Check(TimelineVerdict.REBOOT if back else TimelineVerdict.GAP, last, held)
        if self._held is not None:
            self._held, outlier = None, True
        if last is not None and t <= last:
            return Check(TimelineVerdict.OUT_OF_ORDER, outlier=outlier)
        self.last = t
        return Check(TimelineVerdict.OK, outlier=outlier)
