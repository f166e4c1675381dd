"""taco+'s trigger (search.py): recover while lock is lost (a hexagonal grid of crops growing with the
uncertainty), verify a held answer, confirm a relocalisation, hand over from a lost GNSS, the map trigger, then
distance, covariance and time (longer while the wheels give the speed), each with the cross search sized by the
uncertainty.

World frame ENU metres, times autopilot seconds.
"""

from __future__ import annotations

import numpy as np

from taco_mav.core.estimator import Plan
from taco_mav.core.gnss.fusion import GnssFusion
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.answer_hold import AnswerHold
from taco_mav.core.plus.lock import LockMonitor, LockState
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.progress import Progress
from taco_mav.core.plus.search import cross_arm, grid_rings, hex_offsets
from taco_mav.core.plus.wheel_speed import WheelAiding
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.queries import QueryDesk
from taco_mav.core.search import cross_offsets
from taco_mav.core.timeline import Timeline
from taco_mav.core.types import horizontal_sigma

__all__ = ["PlusTrigger"]


class PlusTrigger:
    """taco+'s trigger on the Localiser's `timeline`, `desk` and `gnss` (see the module docstring)."""

    def __init__(self, timeline: Timeline, desk: QueryDesk, gnss: GnssFusion, params: LocaliserParams,
                 q: PlusParams, *, lock: LockMonitor, progress: Progress, answers: AnswerHold,
                 zero: ZeroVelocity, wheels: WheelAiding | None = None) -> None:
        self.timeline, self.desk, self.gnss, self.p, self.q = timeline, desk, gnss, params, q
        self.lock, self.progress, self.answers, self.zero, self.wheels = lock, progress, answers, zero, wheels
        self._gnss_was_healthy = False  # the real GNSS was in use at the last trigger check

    def plan(self) -> Plan | None:
        """taco+'s trigger (search.py): recover while lock is lost, verify a held answer, confirm, hand over
        from a lost GNSS, the map trigger, distance, covariance, time."""
        tl, q, pr = self.timeline, self.q, self.progress
        sig = horizontal_sigma(tl.ukf.P)
        wheel_cov = self.wheels.scale.covariance() if self.wheels is not None else None
        if wheel_cov is not None:  # the wheels' scale error since the last fix (wheel_scale.py)
            sig = horizontal_sigma(tl.ukf.P[:2, :2] + wheel_cov)
        if self.lock.on_uncertainty(tl.t, sig):
            self.answers.inflate(sig)
            sig = horizontal_sigma(tl.ukf.P)
        if tl.t - self.progress.last_answer_t < q.recover_interval_s:
            return None
        state = self.lock.state
        if state is LockState.LOST:
            rings = min(grid_rings(sig, q) + self.lock.attempts, q.grid_max_rings)
            return self._planned("recover", hex_offsets(rings, q.grid_spacing_m))
        arm = cross_offsets(cross_arm(sig, q), self.p.trigger.multi_crop)
        if any(tl.t - h[1] <= q.confirm_window_s for h in self.answers.held):
            return self._planned("verify", arm)  # a held answer waits for a second one
        if state is LockState.CONFIRMING:
            return self._planned("confirm", arm)
        if self._gnss_handover():
            return self._planned("handover", arm)
        if self._map_anchored(sig):
            return self._planned("map", arm)
        retry = q.defer_retry_m if self.progress.deferred else q.trigger_retry_m
        if (q.trigger_distance_m > 0.0 and pr.odo - pr.odo_at_fix >= q.trigger_distance_m
                and pr.odo - pr.odo_at_query >= retry):
            return self._planned("distance", arm)
        if sig >= q.trigger_sigma_m:
            return self._planned("covariance", arm)
        # also at an apparent stop (one the IMU cannot tell from a smooth cruise must not silence the camera),
        # unless the autopilot confirms it does not drive
        stopped = self.zero.stopped_on_command()
        every = q.trigger_retry_s if q.trigger_retry_s > 0.0 and self.answers.last_answer_weak else q.trigger_time_s
        if self.wheels is not None and self.wheels.in_use(tl.t):  # the speed is known: the covariance decides
            every = max(every, self.wheels.w.trigger_time_s)
        if tl.t - self.desk.answered_t >= every and not (stopped and (self.zero.active or self.zero.still.stationary)):
            return self._planned("time", arm)
        return None

    def _planned(self, reason: str, offsets: np.ndarray) -> Plan:
        self.progress.odo_at_query = self.progress.odo
        self.progress.queries += 1
        return reason, 0.0, offsets

    def _map_anchored(self, sig: float) -> bool:
        """The map trigger (config plus.map_trigger_ratio): with the map's offset as states, the position (1-sigma
        `sig`, m) is known better than map_trigger_ratio times the offset's 1-sigma in its least known direction,
        so a fix now teaches the offset; asked at once, then every map_trigger_m metres while it lasts."""
        ukf = self.timeline.ukf
        if len(ukf.x) < 8 or self.q.map_trigger_ratio <= 0.0:
            return False
        lam_b = float(np.linalg.eigvalsh(ukf.P[6:8, 6:8])[-1])
        if sig * sig >= self.q.map_trigger_ratio**2 * lam_b:
            return False
        pr = self.progress
        return pr.queries == 0 or pr.odo - pr.odo_at_query >= self.q.map_trigger_m

    def _gnss_handover(self) -> bool:
        """True once when the real GNSS that was in use is lost or held off: the camera at once, rather than
        when the uncertainty has grown, takes over from the receiver's wandering position."""
        g = self.gnss.guard
        healthy = g is not None and g.healthy_at(self.timeline.t)
        lost = self._gnss_was_healthy and not healthy
        self._gnss_was_healthy = healthy
        return lost
