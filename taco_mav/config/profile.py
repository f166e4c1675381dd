"""The whole vehicle profile, its plain-dict form, one-field replacement, and the values handed to the core."""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Any

from taco_mav.config.fields import Estimator
from taco_mav.config.link import LinkConfig, OutputConfig
from taco_mav.config.sensors import CameraConfig, ClassicalMatcherConfig, EmulatorConfig, Fg2Config, MapConfig
from taco_mav.core.gnss.params import GnssParams
from taco_mav.core.params import (AnswerParams, ErrorModelParams, GateParams, ImuParams, LatencyParams, LocaliserParams,
                                  SmootherParams, TriggerParams, UkfParams)
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.wheel_params import WheelParams

__all__ = ["MATCHERS", "Profile", "frd_fwd_left", "localiser_params", "profile_to_dict", "replace_in"]

# The matcher names a profile may give (cvgl/registry.py builds them).
MATCHERS: tuple[str, ...] = ("classical", "emulator", "fg2")


@dataclass(frozen=True)
class Profile:
    """A whole vehicle profile. The estimator's sections are the core's own parameter classes (core/params.py,
core/plus/params.py, core/gnss/params.py: one definition, one default each); the sensor and link sections are here."""

    name: str = "default"
    estimator: Estimator = Estimator.PAPER
    matcher: str = "classical"  # classical | emulator | fg2
    imu: ImuParams = ImuParams()
    error_model: ErrorModelParams = ErrorModelParams()
    trigger: TriggerParams = TriggerParams()
    gate: GateParams = GateParams()
    answer: AnswerParams = AnswerParams()
    ukf: UkfParams = UkfParams()
    smoother: SmootherParams = SmootherParams()
    plus: PlusParams = PlusParams()
    gnss: GnssParams = GnssParams()
    latency: LatencyParams = LatencyParams()
    camera: CameraConfig = CameraConfig()
    map: MapConfig = MapConfig()
    classical: ClassicalMatcherConfig = ClassicalMatcherConfig()
    emulator: EmulatorConfig = EmulatorConfig()
    fg2: Fg2Config = Fg2Config()
    link: LinkConfig = LinkConfig()
    output: OutputConfig = OutputConfig()
    wheels: WheelParams = WheelParams()


def replace_in(profile: Profile, dotted: str, value: Any) -> Profile:
    """Return a copy with one nested field replaced, e.g. replace_in(p, "gate.enabled", False)."""
    head, _, rest = dotted.partition(".")
    if not rest:
        return dataclasses.replace(profile, **{head: value})
    return dataclasses.replace(profile, **{head: replace_in(getattr(profile, head), rest, value)})


def profile_to_dict(obj: Any) -> Any:
    """A plain, YAML/JSON-ready mapping of a profile (the resolved config written beside results)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: profile_to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, tuple):
        return [profile_to_dict(v) for v in obj]
    return obj


def frd_fwd_left(position_frd_m: tuple[float, float, float]) -> tuple[float, float]:
    """Body FRD [x forward, y right, z down] metres (a profile's camera.position_frd_m, output.antenna_frd_m) ->
    the horizontal (forward, left) metres the core uses."""
    return float(position_frd_m[0]), -float(position_frd_m[1])


def localiser_params(profile: Profile) -> LocaliserParams:
    """The values the core Localiser takes, from a profile (the core never sees the Profile itself): its estimator
    sections as they are, the camera's lever arm, the map's georeferencing error, taco+ only in that mode, and the
    wheels only when enabled."""
    return LocaliserParams(
        imu=profile.imu, error_model=profile.error_model, trigger=profile.trigger, gate=profile.gate, answer=profile.answer,
        ukf=profile.ukf, smoother=profile.smoother, latency=profile.latency,
        camera_lever_fwd_left_m=frd_fwd_left(profile.camera.position_frd_m),
        map_georef_sigma_m=profile.map.georef_sigma_m,
        plus=profile.plus if profile.estimator is Estimator.TACO_PLUS else None, gnss=profile.gnss,
        wheels=profile.wheels if profile.wheels.enabled else None)
