"""The simulator's true pose as the link gives it (SIMSTATE on ArduPilot SITL, HIL_STATE_QUATERNION on PX4 SIH),
kept for a matcher that answers from it (`Matcher.needs_true_pose`: the FG2-statistics emulator). The daemon
makes one only for such a matcher: a simulator streams its true pose at its data rate (100 Hz) to a real
camera's run too, and nothing else reads it.

Threads: `add` and `clear` run on the daemon loop thread, `__call__` in the matcher worker. Times are autopilot
seconds; positions absolute UTM metres of the origin's zone; headings ENU (UTM grid) radians.
"""

from __future__ import annotations

import math
import threading
from collections import deque

from taco_mav.mavlink import encoders
from taco_mav.mavlink.decoders import SimPose

__all__ = ["TruePoseTrack"]

KEPT = 3000  # poses kept: 30 s at a simulator's 100 Hz, far longer than a query waits for its answer


class TruePoseTrack:
    """The latest KEPT true poses, (t, E, N, theta); called as a true-pose matcher's `TruthFn`: truth(t) -> (E, N, theta)
    of the pose nearest autopilot time t."""

    def __init__(self) -> None:
        self.poses: deque[tuple[float, float, float, float]] = deque(maxlen=KEPT)
        self._lock = threading.Lock()  # appended by the loop thread, searched by the matcher worker

    def add(self, t: float, pose: SimPose, origin: encoders.Origin) -> None:
        """The true pose at autopilot time t (s), projected onto the origin's UTM grid."""
        e, n = origin.projector.to_utm(pose.lat, pose.lon)
        theta = math.remainder(math.pi / 2 - pose.yaw + origin.convergence, 2 * math.pi)
        with self._lock:
            self.poses.append((t, float(e), float(n), theta))

    def clear(self) -> None:
        """Forget every pose (the autopilot clock restarted)."""
        with self._lock:
            self.poses.clear()

    def __call__(self, t: float) -> tuple[float, float, float]:
        """The pose nearest autopilot time t (s): absolute UTM E, N metres and grid heading (rad)."""
        with self._lock:
            if not self.poses:
                raise RuntimeError("no SIMSTATE received: the emulator matcher needs the simulator's true pose")
            best = min(self.poses, key=lambda s: abs(s[0] - t))
        return best[1], best[2], best[3]
