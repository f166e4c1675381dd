"""Plain parameter values for the Localiser (built from a vehicle profile by `config.localiser_params`; the
defaults are the paper's, see config.py for the section citations). Lengths metres, angles radians, times s."""

from __future__ import annotations

from dataclasses import dataclass, field

from taco_mav.core.gnss_guard import GnssParams
from taco_mav.core.plus import PlusParams
from taco_mav.core.smoother import SmootherParams


@dataclass(frozen=True)
class LocaliserParams:
    # preintegration and error model (Sec. III-B)
    frame_rate_hz: float = 10.0
    gyro_arw: float = 8.7e-5
    accel_highpass_hz: float = 0.2
    allow_reverse: bool = False
    max_dt_s: float = 0.5
    error_cross_k: float = 3.0
    error_along_k: float = 0.5
    error_divergence_k: float = 0.03
    # trigger and search (Sec. III-D)
    trigger_epsilon_m: float = 1.0
    trigger_time_s: float = 2.0
    forward_bias: bool = True
    forward_bias_k: float = 0.4
    forward_bias_cap_m: float = 15.0
    multi_crop: bool = True
    # the camera's position relative to the vehicle reference point, body (forward, left) metres: the lever arm
    # that fix_position takes off every matcher answer (profile camera.position_frd_m; zero = camera at the point)
    camera_lever_fwd_left_m: tuple[float, float] = (0.0, 0.0)
    search_cross_k: float = 0.5
    cross_cap_m: float = 10.0
    query_timeout_s: float = 5.0
    # yaw gate (Sec. III-E)
    yaw_gate: bool = True
    yaw_residual_max_rad: float = 0.35
    # UKF (Sec. III-F)
    ukf_alpha: float = 1e-3
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0
    sigma_fwd_min_m: float = 1.0
    sigma_fwd_k: float = 2.0
    sigma_lat_min_m: float = 1.5
    sigma_lat_k: float = 0.3
    sigma_theta_rad: float = 0.05
    fix_fwd_num: float = 1.5
    fix_fwd_min_m: float = 0.5
    fix_fwd_max_m: float = 8.0
    fix_lat_num: float = 3.0
    fix_lat_min_m: float = 1.0
    fix_lat_max_m: float = 12.0
    anisotropic: bool = True
    compass_sigma_rad: float = 0.05
    initial_sigma_xy_m: float = 0.01
    initial_sigma_theta_rad: float = 0.05
    # delayed fixes
    apply_on_arrival: bool = False
    history_s: float = 10.0
    # smoother (Sec. III-G)
    smoother: SmootherParams = field(default_factory=SmootherParams)
    # the map's georeferencing 1-sigma per axis, m: taco+ then carries the map's offset as two filter states
    # (profile map.georef_sigma_m; 0: the map is exact, as in the paper)
    map_georef_sigma_m: float = 0.0
    # taco+ (issue 7): None = paper mode
    plus: PlusParams | None = None
    # real GNSS while it is honest, and the spoofing/jamming guard (issue 14)
    gnss: GnssParams = field(default_factory=GnssParams)
