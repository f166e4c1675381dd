"""Matcher factory by profile name: "classical" (CPU), "emulator" (FG2 statistics, needs truth), "fg2" (torch).

Implementations are imported lazily so that, e.g., torch is only needed when the fg2 matcher is asked for (the
fg2 module itself imports torch only when a matcher is built, so asking a class what it needs loads no torch).
"""

from __future__ import annotations

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import MATCHERS, Profile, frd_fwd_left
from taco_mav.cvgl.base import Matcher, TruthFn
from taco_mav.errors import ConfigError, MatcherError

__all__ = ["MATCHERS", "make_matcher", "needs_true_pose"]


def _matcher_class(name: str) -> type[Matcher]:
    """The class of matcher `name`, imported here (ConfigError for a name not in MATCHERS)."""
    if name == "classical":
        from taco_mav.cvgl.classical import ClassicalMatcher

        return ClassicalMatcher
    if name == "emulator":
        from taco_mav.cvgl.emulator import EmulatorMatcher

        return EmulatorMatcher
    if name == "fg2":
        from taco_mav.cvgl.fg2.adapter import Fg2Matcher

        return Fg2Matcher
    raise ConfigError(f"matcher: {name!r} is not one of {', '.join(MATCHERS)}")


def needs_true_pose(profile: Profile, matcher: Matcher | None = None) -> bool:
    """Whether the matcher in use answers from the simulator's true pose (`Matcher.needs_true_pose`): `matcher`
    when one is given (it stands in for the profile's), else the class of `profile.matcher`. Such a matcher is
    built with a `TruthFn` and needs neither a camera nor a map."""
    return matcher.needs_true_pose if matcher is not None else _matcher_class(profile.matcher).needs_true_pose


def make_matcher(profile: Profile, truth: TruthFn | None = None, *, cross_area: bool = False,
                 camera: GroundCamera | None = None) -> Matcher:
    """Build `profile.matcher`. truth(t) -> (E, N, theta) (absolute UTM metres, ENU rad) is required by a
    matcher that answers from the true pose (the emulator) and unused by the others; cross_area selects the
    emulator's cross-area figures; camera defaults to profile.camera."""
    camera = camera or GroundCamera.from_config(profile.camera)
    name = profile.matcher
    if _matcher_class(name).needs_true_pose and truth is None:
        raise MatcherError(f"matcher {name!r} needs ground truth (it is a statistical model for simulation "
                           "and evaluation, not a localiser); use 'classical' or 'fg2' on a vehicle")
    if name == "classical":
        from taco_mav.cvgl.classical import ClassicalMatcher

        return ClassicalMatcher(profile.classical, camera)
    if name == "emulator":
        from taco_mav.cvgl.emulator import EmulatorMatcher

        assert truth is not None
        return EmulatorMatcher(profile.emulator, truth, cross_area=cross_area,
                               lever_fwd_left=frd_fwd_left(profile.camera.position_frd_m))
    from taco_mav.cvgl.fg2.adapter import Fg2Matcher

    return Fg2Matcher(profile.fg2, camera)
