"""Vehicle profiles: frozen dataclasses with the paper's values as defaults, loaded from YAML.

Every TACO parameter is named here, defaulted to the value in `../shared/paper/TACO.tex`, and cited by
section ("Sec. III-B" = Methodology, IMU Preintegration and Error Model; III-D = Triggering and Multi-Crop
Search; III-E = Yaw-Residual Gate; III-F = UKF Fusion; III-G = Factor Graph and Loop Closure; IV = Results).
Values the paper does not give are marked "not in the paper" with the reason for our choice.

A profile YAML mirrors the nesting of `Profile`; any key it leaves out keeps its default. Unknown keys,
wrong types and out-of-range values raise `ConfigError` naming the file and the dotted key.

One module per concern, every public name re-exported here (`from taco_mav.config import X`):

- `fields`: `Estimator` and the `bounded` range metadata every section uses;
- the estimator's sections are the core's parameter classes, defined once there and re-exported here:
  core/params.py (the paper's imu, error_model, trigger, gate, ukf, smoother, and latency), core/plus/params.py
  (taco+), core/gnss/params.py (the GNSS guard);
- `sensors`: camera, map and the matchers (classical, emulator, fg2);
- `link`: the MAVLink link and the daemon's output;
- `profile`: `Profile`, `replace_in`, `profile_to_dict`, `localiser_params`;
- `loading`: YAML -> `Profile` with validation, shipped profiles by name.
"""

from __future__ import annotations

from taco_mav.config.fields import Estimator, bounded
from taco_mav.config.link import LinkConfig, OutputConfig
from taco_mav.config.loading import (LOCAL_PROFILE_DIR, PROFILE_DIR, load_profile, parse_overrides, profile_from_dict,
                                     resolve_profile_path, shipped_profiles)
from taco_mav.config.profile import MATCHERS, Profile, frd_fwd_left, localiser_params, profile_to_dict, replace_in
from taco_mav.config.sensors import CameraConfig, ClassicalMatcherConfig, EmulatorConfig, Fg2Config, MapConfig
from taco_mav.core.gnss.params import GnssParams
from taco_mav.core.params import (ErrorModelParams, GateParams, ImuParams, LatencyParams, SmootherParams, TriggerParams,
                                  UkfParams)
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.wheel_params import WheelParams

__all__ = ["LOCAL_PROFILE_DIR", "MATCHERS", "PROFILE_DIR", "CameraConfig", "ClassicalMatcherConfig",
           "EmulatorConfig", "ErrorModelParams", "Estimator", "Fg2Config", "GateParams", "GnssParams", "ImuParams",
           "LatencyParams", "LinkConfig", "MapConfig", "OutputConfig", "PlusParams", "Profile", "SmootherParams",
           "TriggerParams", "UkfParams", "WheelParams", "bounded", "frd_fwd_left", "load_profile", "localiser_params",
           "parse_overrides", "profile_from_dict", "profile_to_dict", "replace_in", "resolve_profile_path",
           "shipped_profiles"]
