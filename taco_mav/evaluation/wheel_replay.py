"""A recording's wheel encoders replayed into the Localiser as the daemon feeds them (daemon/wheels.py): each
WHEEL_DISTANCE sample differenced by core/wheel_odometry.py and handed to taco+ once the IMU has reached its
time, so `taco-mav eval --tlog` fuses what the daemon fused. Times autopilot seconds."""

from __future__ import annotations

import logging
from collections import Counter

from taco_mav.core.localiser import Localiser
from taco_mav.core.wheel_odometry import WheelOdometry
from taco_mav.core.wheel_params import WheelParams
from taco_mav.datasets.base import WheelLog

log = logging.getLogger(__name__)

__all__ = ["WheelReplay"]


class WheelReplay:
    """wheels: the recorded samples; w: the profile's wheels section (the recorded WENC_POS_Y / WENC2_POS_Y
    replace wheel_pos_y_m with pos_y_from_autopilot, as in the daemon). `counts`: what became of each sample."""

    def __init__(self, wheels: WheelLog, w: WheelParams) -> None:
        self.wheels = wheels
        pos_y = wheels.pos_y_m if w.pos_y_from_autopilot and wheels.pos_y_m is not None else w.wheel_pos_y_m
        self.odometry = WheelOdometry(pos_y, w.max_speed_mps)
        self.counts: Counter[str] = Counter()
        self._k = 0

    def tick(self, loc: Localiser, t: float) -> None:
        """Hand `loc` every sample up to autopilot time t (s) not yet handed."""
        ts, ds = self.wheels.t, self.wheels.distances
        while self._k < len(ts) and ts[self._k] <= t:
            m = self.odometry.add(float(ts[self._k]), ds[self._k])
            self._k += 1
            if isinstance(m, str):
                self.counts[m] += 1
            elif loc.aids is not None:
                self.counts[loc.aids.add_wheel_speed(m)] += 1
