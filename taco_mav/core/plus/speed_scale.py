"""The camera speed's scale error as a consider term of taco+ (plus.speed_scale_consider).

A camera that measures the ground's motion gets its scale from the mount height and pitch, and a 3 cm error in a
1 m height is a 3 % error in every speed it measures (plus.camera_speed_scale_sigma). The filter fuses each
measurement with that 3 % in its variance but as white noise, so 20 measurements between two fixes average it
down, while the real error is the same in all of them. With the camera's speed steering the speed estimate, the
position then runs ahead or behind by the scale error times the displacement since the position was last pinned
(a fix, a fused GNSS reading): PX4 SIH's hand-overs put the estimate 0.8-1.0 m ahead after the 30 m between fixes,
with 0.5 m reported (docs/px4.md).

`ScaleConsider` carries that error beside the filter, as a consider state of a Schmidt filter would (its variance,
never an estimate of it): the ENU displacement D driven while the camera's speed was in use since the last pin,
and the covariance sigma^2 D D^T it puts on the position. taco+ adds it to the accuracy it reports, and at an
accepted fix to the position covariance at the fix's capture before the update, so the fix is weighed against
the error the estimate really carries and what the fix leaves of it stays in P; the term restarts there. A
rejected answer changes nothing; a fused GNSS reading (metres at 5-10 Hz, centimetres of D between readings)
restarts it without more.

Lengths metres (ENU), times autopilot seconds.
"""

from __future__ import annotations

import math

import numpy as np

from taco_mav.core.frames import Tick

# The camera's speed steers the speed estimate for this long after a measurement was used, s: the motion loop
# measures every 0.5 s (daemon/motion.py), so three periods; beyond it the IMU carries the speed, and its own error
# growth is the process noise's (plus.q_speed_mps).
CAMERA_SPEED_HOLD_S = 1.5


class ScaleConsider:
    """The displacement (ENU metres) driven on the camera's speed since the position was last pinned, and the
    covariance (m^2) a scale error of 1-sigma `sigma` (dimensionless) puts on it."""

    def __init__(self, sigma: float) -> None:
        self.sigma = float(sigma)
        self.track = np.zeros(2)  # cumulative displacement on the camera's speed, ENU m
        self.pinned = np.zeros(2)  # `track` where the position was last pinned
        self._camera_used_t = -math.inf

    def camera_used(self, t: float) -> None:
        """A camera speed measurement ending at autopilot time t was fused."""
        self._camera_used_t = max(self._camera_used_t, float(t))

    def advance(self, tick: Tick, heading_mid: float) -> None:
        """Add the frame's forward displacement (tick.inc.d_fwd, m, signed) along heading_mid (ENU rad) while the
        camera's speed is in use, and store the running total on the tick (a late fix pins at its capture)."""
        if tick.t - self._camera_used_t <= CAMERA_SPEED_HOLD_S:
            d = float(tick.inc.d_fwd)
            self.track = self.track + d * np.array([math.cos(heading_mid), math.sin(heading_mid)])
        tick.scale_track = (float(self.track[0]), float(self.track[1]))

    def pin(self, tick: Tick | None = None) -> None:
        """The position was pinned at `tick` (an accepted fix at its capture frame) or now (None: a fused GNSS
        reading)."""
        at = tick.scale_track if tick is not None else None
        self.pinned = np.array(at) if at is not None else self.track.copy()

    def covariance(self) -> np.ndarray:
        """sigma^2 D D^T, D the displacement since the last pin to now, ENU m^2 (2x2)."""
        return self._of(self.track)

    def covariance_at(self, tick: Tick) -> np.ndarray:
        """sigma^2 D D^T to the history frame `tick` (a late fix's capture), ENU m^2 (2x2)."""
        return self._of(np.array(tick.scale_track) if tick.scale_track is not None else self.track)

    def _of(self, track: np.ndarray) -> np.ndarray:
        d = track - self.pinned
        return self.sigma * self.sigma * np.outer(d, d)
