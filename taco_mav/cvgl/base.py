"""The matcher contract (paper Sec. III-C): frames, units and shapes, stated once.

A trigger asks for K crops (K = 5 in paper mode) of the satellite mosaic, each centred on a candidate UTM
position and rotated heading-up (the query heading theta points to image-up; h_img = pi/2 - theta). The
matcher gets the one ground frame and the K crops and returns K `MatchResult`s in the same order:

- R: 2x2 residual rotation of the matcher's heading against the query heading (CCW positive);
- t: the CAMERA's ground position (the point below its optical centre) relative to the crop centre, metres, as
  (forward, left) in the heading-up crop (forward = image up, left = image left). What a matcher sees is the
  camera; the vehicle reference point is elsewhere (profile camera.position_frd_m, the lever arm), and
  `fix_position` alone takes the lever arm off;
- w: match weight in (0, 1]; higher is more confident.

`taco_mav.core.search.fix_position` turns (crop centre, heading, t, lever arm) into a world fix of the vehicle
reference point; nothing else does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.core.types import MatchResult

__all__ = ["Crop", "GroundFrame", "Matcher", "MatchResult", "TruthFn"]

TruthFn = Callable[[float], tuple[float, float, float]]
"""truth(t) -> (E, N, theta): the true absolute UTM metres and ENU heading (rad) of the vehicle reference point at
time t (s), for a matcher that answers from the true pose (`Matcher.needs_true_pose`)."""


@dataclass(frozen=True)
class Crop:
    """A heading-up satellite crop. image: uint8 RGB (S, S, 3); centre_utm: (2,) absolute UTM E, N metres of
    the crop centre; heading: the query heading, ENU radians; m_per_px: metres per pixel; valid_fraction: share
    of pixels that came from the mosaic (1.0 = fully on the map)."""

    image: np.ndarray
    centre_utm: np.ndarray
    heading: float
    m_per_px: float
    valid_fraction: float = 1.0


@dataclass(frozen=True)
class GroundFrame:
    """A ground camera frame. image: uint8 RGB (H, W, 3) (grey (H, W) where the consumer asked for grey: the
    daemon's camera speed); t: capture time on the autopilot clock, s;
    camera: its flat-ground pinhole model."""

    image: np.ndarray
    t: float
    camera: GroundCamera


class Matcher(Protocol):
    """Anything that localises one ground frame against K heading-up crops. needs_true_pose: the matcher draws its
    answers from the simulator's true pose (the emulator, built with a `TruthFn`) and never looks at the
    frame's or the crops' pixels, so it needs neither a camera nor a map; False for matchers that see images."""

    name: str
    needs_true_pose: bool

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        """One MatchResult per crop, in order."""
        ...
