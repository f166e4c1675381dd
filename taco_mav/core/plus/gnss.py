"""taco+'s use of a real GNSS (the measurement and its checks are `gnss/fusion.py`): a Kalman update of position,
speed and course on the taco+ state, instead of the paper mode's re-anchoring. A part of taco+ (estimator.py), applied
through the timeline as a `GnssCorrection`.

World frame ENU metres, speeds m/s, angles radians (ENU, CCW).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from taco_mav.core.frames import GnssMeasurement, Tick
from taco_mav.core.gnss.guard import receiver_variances
from taco_mav.core.timeline import Timeline
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.plus.safety_guard import SafetyGuard
from taco_mav.core.plus.zero_velocity import ZeroVelocity
from taco_mav.core.preintegration import wrap_angle
from taco_mav.core.ukf import PlanarUkf, joseph_update


class KalmanGnss:
    """Real-GNSS updates on the taco+ filter of the Localiser's `timeline`: `feedback` moves the speed error into the
    preintegrator (`PlusAids.feedback`); a speed reading is a speed observation for stops (`zero`); the safety
    `guard` restarts its IMU-only track after a batch."""

    replaces = False  # a Kalman update, not a re-anchoring

    def __init__(self, timeline: Timeline, q: PlusParams, zero: ZeroVelocity, guard: SafetyGuard,
                 feedback: Callable[[Tick], None]) -> None:
        self.timeline, self.q, self.zero, self.guard, self._feedback = timeline, q, zero, guard, feedback

    def apply(self, ukf: PlanarUkf, tick: Tick, m: GnssMeasurement) -> None:
        """Kalman update at `tick`: position (isotropic sigma_h) and, when the reading has a speed (above
        gnss.min_speed_mps), the speed error x[3] (the ground speed at the frame end against the preintegrated
        speed there, m/s) and the heading x[2] (the course; as the compass reads theta + beta this makes the
        compass bias x[5] observable, and the speed the accelerometer bias x[4]). The receiver's wander (the
        bias share of sigma_h, see gnss_guard) stays in the position covariance as a floor: averaging readings
        does not remove it, and the reported accuracy, the camera gates and the hand-over to dead reckoning must
        know it."""
        x, P = ukf.get_state()
        rows, innov, var = [0, 1], [m.xy[0] - x[0], m.xy[1] - x[1]], [m.var_xy, m.var_xy]
        if m.speed is not None:
            rows.append(3)
            innov.append(m.speed - (tick.inc.speed_end + tick.dv_fed) - x[3])
            var.append(m.var_speed)
        if m.course is not None:
            rows.append(2)
            innov.append(wrap_angle(m.course - x[2]))
            var.append(m.var_course)
        H = np.zeros((len(rows), len(x)))
        H[np.arange(len(rows)), rows] = 1.0
        x, P, _ = joseph_update(x, P, H, np.array(innov), np.diag(var))
        x[2] = wrap_angle(x[2])
        floor = receiver_variances(math.sqrt(m.var_xy), self.timeline.p.gnss)[1]
        lo = float(np.linalg.eigvalsh(P[:2, :2]).min())
        if lo < floor:
            P[:2, :2] += (floor - lo) * np.eye(2)
        ukf.set_state(x, P)

    def fused(self, tick: Tick, m: GnssMeasurement) -> None:
        """After a batch of readings: feed the speed error back, as after an accepted fix."""
        if self.timeline.history:
            self._feedback(self.timeline.history[-1])
        if m.speed is not None:
            self.zero.seen(math.sqrt(max(float(self.timeline.ukf.P[3, 3]), 0.0)))
        if self.q.guard:
            self.guard.reset()

    def anchor_terms(self, tick: Tick) -> tuple[float, float, float, tuple[float, float, float]]:
        """(true-speed estimate m/s, accelerometer bias m/s^2, compass bias rad, their 1-sigmas with the
        heading's) at tick's end, from the taco+ states."""
        x, P = tick.x, tick.P
        beta = float(x[5]) if len(x) > 5 else 0.0
        var_heading = float(P[5, 5]) if len(x) > 5 else float(P[2, 2])
        sig = tuple(math.sqrt(max(v, 0.0)) for v in (float(P[3, 3]), float(P[4, 4]), var_heading))
        return float(tick.inc.speed_end + tick.dv_fed + x[3]), float(x[4]), beta, sig
