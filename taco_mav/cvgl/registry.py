"""Matcher factory by profile name: "classical" (CPU), "emulator" (FG2 statistics, needs truth), "fg2" (torch).

Implementations are imported lazily so that, e.g., torch is only needed when the fg2 matcher is asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import MATCHERS, Profile, frd_fwd_left
from taco_mav.cvgl.base import Matcher
from taco_mav.errors import ConfigError, MatcherError

if TYPE_CHECKING:  # the emulator module loads only for the emulator (a vehicle's run never needs it)
    from taco_mav.cvgl.emulator import TruthFn

__all__ = ["MATCHERS", "make_matcher"]


def make_matcher(profile: Profile, truth: TruthFn | None = None, *, cross_area: bool = False,
                 camera: GroundCamera | None = None) -> Matcher:
    """Build `profile.matcher`. truth(t) -> (E, N, theta) (absolute UTM metres, ENU rad) is required by the
    emulator only; cross_area selects the emulator's cross-area figures; camera defaults to profile.camera."""
    camera = camera or GroundCamera.from_config(profile.camera)
    name = profile.matcher
    if name == "classical":
        from taco_mav.cvgl.classical import ClassicalMatcher

        return ClassicalMatcher(profile.classical, camera)
    if name == "emulator":
        if truth is None:
            raise MatcherError("matcher 'emulator' needs ground truth (it is a statistical model for simulation "
                               "and evaluation, not a localiser); use 'classical' or 'fg2' on a vehicle")
        from taco_mav.cvgl.emulator import EmulatorMatcher

        return EmulatorMatcher(profile.emulator, truth, cross_area=cross_area,
                               lever_fwd_left=frd_fwd_left(profile.camera.position_frd_m))
    if name == "fg2":
        from taco_mav.cvgl.fg2.adapter import Fg2Matcher

        return Fg2Matcher(profile.fg2, camera)
    raise ConfigError(f"matcher: {name!r} is not one of {', '.join(MATCHERS)}")
