"""What the daemon's handlers share, and only that: the origin and the Localiser generations (`LocaliserAnchor`), the
current Localiser, the latest attitude and IMU reading, and when that reading arrived on the companion clock.
The input handler writes the readings and anchors the Localiser; the origin handler sets the origin and feeds
real GNSS; the output handler reads the estimate. Everything else a handler keeps is its own."""

from __future__ import annotations

import math
from dataclasses import dataclass

from taco_mav.core.localiser import Localiser
from taco_mav.daemon.anchor import LocaliserAnchor
from taco_mav.daemon.shadow import Shadow
from taco_mav.mavlink import encoders
from taco_mav.mavlink.decoders import AttitudeReading, ImuReading

__all__ = ["LiveState"]


@dataclass
class LiveState:
    """anchor: origin and Localiser generations (+1 at each re-anchoring); loc: None until the first IMU sample
    after the origin; attitude: the latest valid attitude (autopilot time); last_imu: the latest IMU reading fed
    (None again after a reboot); last_imu_clock: companion seconds when it arrived (the output's stall check)."""

    anchor: LocaliserAnchor
    loc: Localiser | None = None
    attitude: AttitudeReading | None = None
    last_imu: ImuReading | None = None
    last_imu_clock: float = -math.inf
    shadow: Shadow | None = None  # --shadow: the GNSS-free twin beside loc

    @property
    def twin(self) -> Localiser | None:
        """The shadow twin fed what loc is fed except GNSS (None without --shadow or before anchoring)."""
        return self.shadow.twin if self.shadow is not None else None

    @property
    def origin(self) -> encoders.Origin | None:
        """The origin (start fix and UTM frame), None until one is taken."""
        return self.anchor.origin
