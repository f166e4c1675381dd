"""The whole vehicle profile, its plain-dict form, one-field replacement, and the values handed to the core."""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from taco_mav.config.fields import Estimator
from taco_mav.config.link import LinkConfig, OutputConfig
from taco_mav.config.paper import (ErrorModelConfig, GateConfig, ImuConfig, LatencyConfig, SmootherConfig,
                                   TriggerConfig, UkfConfig)
from taco_mav.config.plus import GnssConfig, PlusConfig
from taco_mav.config.sensors import CameraConfig, ClassicalMatcherConfig, EmulatorConfig, Fg2Config, MapConfig

if TYPE_CHECKING:
    from taco_mav.core.params import LocaliserParams

__all__ = ["MATCHERS", "Profile", "frd_fwd_left", "localiser_params", "profile_to_dict", "replace_in"]

# The matcher names a profile may give (cvgl/registry.py builds them).
MATCHERS: tuple[str, ...] = ("classical", "emulator", "fg2")


@dataclass(frozen=True)
class Profile:
    """A whole vehicle profile."""

    name: str = "default"
    estimator: Estimator = Estimator.PAPER
    matcher: str = "classical"  # classical | emulator | fg2
    imu: ImuConfig = ImuConfig()
    error_model: ErrorModelConfig = ErrorModelConfig()
    trigger: TriggerConfig = TriggerConfig()
    gate: GateConfig = GateConfig()
    ukf: UkfConfig = UkfConfig()
    smoother: SmootherConfig = SmootherConfig()
    plus: PlusConfig = PlusConfig()
    gnss: GnssConfig = GnssConfig()
    latency: LatencyConfig = LatencyConfig()
    camera: CameraConfig = CameraConfig()
    map: MapConfig = MapConfig()
    classical: ClassicalMatcherConfig = ClassicalMatcherConfig()
    emulator: EmulatorConfig = EmulatorConfig()
    fg2: Fg2Config = Fg2Config()
    link: LinkConfig = LinkConfig()
    output: OutputConfig = OutputConfig()


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


def localiser_params(profile: Profile) -> "LocaliserParams":
    """The plain values the core Localiser takes, from a profile (core never sees the Profile itself)."""
    from taco_mav.core.gnss_guard import GnssParams
    from taco_mav.core.params import LocaliserParams
    from taco_mav.core.plus import PlusParams
    from taco_mav.core.smoother import SmootherParams

    imu, em, tr, gate, ukf, sm, lat = (profile.imu, profile.error_model, profile.trigger, profile.gate,
                                       profile.ukf, profile.smoother, profile.latency)
    return LocaliserParams(
        frame_rate_hz=imu.frame_rate_hz, gyro_arw=imu.gyro_arw, accel_highpass_hz=imu.accel_highpass_hz,
        allow_reverse=imu.allow_reverse, max_dt_s=imu.max_dt_s,
        error_cross_k=em.cross_k, error_along_k=em.along_k, error_divergence_k=em.divergence_k,
        trigger_epsilon_m=tr.epsilon_m, trigger_time_s=tr.time_s, forward_bias=tr.forward_bias,
        forward_bias_k=tr.forward_bias_k, forward_bias_cap_m=tr.forward_bias_cap_m, multi_crop=tr.multi_crop,
        camera_lever_fwd_left_m=frd_fwd_left(profile.camera.position_frd_m),
        search_cross_k=tr.cross_k, cross_cap_m=tr.cross_cap_m, query_timeout_s=tr.query_timeout_s,
        yaw_gate=gate.enabled, yaw_residual_max_rad=gate.yaw_residual_max_rad,
        ukf_alpha=ukf.alpha, ukf_beta=ukf.beta, ukf_kappa=ukf.kappa,
        sigma_fwd_min_m=ukf.sigma_fwd_min_m, sigma_fwd_k=ukf.sigma_fwd_k, sigma_lat_min_m=ukf.sigma_lat_min_m,
        sigma_lat_k=ukf.sigma_lat_k, sigma_theta_rad=ukf.sigma_theta_rad,
        fix_fwd_num=ukf.fix_fwd_num, fix_fwd_min_m=ukf.fix_fwd_min_m, fix_fwd_max_m=ukf.fix_fwd_max_m,
        fix_lat_num=ukf.fix_lat_num, fix_lat_min_m=ukf.fix_lat_min_m, fix_lat_max_m=ukf.fix_lat_max_m,
        anisotropic=ukf.anisotropic, compass_sigma_rad=ukf.compass_sigma_rad,
        initial_sigma_xy_m=ukf.initial_sigma_xy_m, initial_sigma_theta_rad=ukf.initial_sigma_theta_rad,
        apply_on_arrival=lat.apply_on_arrival, history_s=lat.history_s,
        smoother=SmootherParams(
            origin_sigma=sm.origin_sigma, nonholonomic_sigma_m=sm.nonholonomic_sigma_m,
            lc_max_chord_m=sm.lc_max_chord_m, lc_min_frame_gap=sm.lc_min_frame_gap,
            lc_min_path_ratio=sm.lc_min_path_ratio, lc_sigma_floor_m=sm.lc_sigma_floor_m,
            lm_max_iterations=sm.lm_max_iterations, lm_relative_tolerance=sm.lm_relative_tolerance,
            savgol_window=sm.savgol_window, savgol_order=sm.savgol_order),
        gnss=GnssParams(**{f.name: getattr(profile.gnss, f.name) for f in dataclasses.fields(GnssConfig)}),
        map_georef_sigma_m=profile.map.georef_sigma_m,
        plus=(PlusParams(**{f.name: getattr(profile.plus, f.name) for f in dataclasses.fields(PlusConfig)})
              if profile.estimator is Estimator.TACO_PLUS else None),
    )
