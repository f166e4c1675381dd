"""Camera speed in an offline run (the measurement the daemon takes in `daemon/motion.py`): every
`interval_s` of IMU time, the ground-plane motion between the drive's frames nearest t - lag - gap and t - lag
(`cvgl.ground_motion.GroundMotion`) goes to taco+'s `add_ground_motion`. The daemon measures on a worker
thread; here it is measured at once, so a re-run gives the same numbers. Without it an offline taco+ run on a
camera drive would use less than the live daemon does (on a 3-D world with the automotive IMU, the speed error
between fixes is what the camera holds down).

Times are the drive's (IMU) seconds; headings ENU radians (the Localiser's compass heading, for the heading
change between the two frames).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.cvgl.ground_motion import MIN_GAP_S, GroundMotion, HeadingHistory
from taco_mav.datasets.base import Drive

__all__ = ["OfflineMotion"]


class OfflineMotion:
    """drive: its frame_times (s, at least two) and frame(i) images; camera: the drive's ground camera; ego_rows:
    the image rows showing the vehicle (the profile's `classical.ego_mask_rows`, as the daemon's). interval_s,
    gap_s and lag_s as `link.motion.MotionPipeline`'s. `counts` says what became of each measurement."""

    def __init__(self, drive: Drive, camera: GroundCamera, ego_rows: int = 0, interval_s: float = 0.5,
                 gap_s: float = 0.3, lag_s: float = 0.1) -> None:
        self.drive = drive
        self.times = np.asarray(drive.frame_times, dtype=float)
        self.motion = GroundMotion(camera, ego_rows=ego_rows)
        self.interval_s, self.gap_s, self.lag_s = interval_s, gap_s, lag_s
        self.counts: Counter[str] = Counter()
        self._next = -math.inf
        self.headings = HeadingHistory()

    def tick(self, loc) -> None:
        """After each IMU sample: record the heading; when a measurement is due, measure and hand it to `loc`
        (taco+)."""
        self.headings.add(float(loc.t), float(loc.timeline.pre.theta))
        if loc.t < self._next:
            return
        self._next = loc.t + self.interval_s
        t1 = loc.t - self.lag_s
        i0, i1 = self._nearest(t1 - self.motion.frame_gap(float(loc.timeline.pre.speed), self.gap_s)), self._nearest(t1)
        ta, tb = float(self.times[i0]), float(self.times[i1])
        if tb - ta < 0.5 * MIN_GAP_S or tb > loc.t:
            self.counts["same_frame" if tb - ta < 0.5 * MIN_GAP_S else "future_frame"] += 1
            return
        dtheta = self.headings.change(ta, tb)
        if dtheta is None:
            self.counts["no_heading"] += 1
            return
        m = self.motion.measure(self.drive.frame(i0), self.drive.frame(i1), dtheta)
        if m is None:
            self.counts["weak"] += 1
            return
        self.counts[loc.add_ground_motion(ta, tb, m.d_fwd, m.d_left, m.sigma_m)] += 1

    def _nearest(self, t: float) -> int:
        return int(np.argmin(np.abs(self.times - t)))
