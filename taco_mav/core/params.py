"""The Localiser's parameters: the paper's sections (Sec. III-B to III-G of `paper/TACO.tex`), the fix-latency
settings, and `LocaliserParams`, which composes them with taco+'s and the GNSS guard's. Each parameter is defined
once, here or in plus/params.py / gnss/params.py, with its one default and where it comes from: the paper's value
cited by section ("Sec. III-B" = IMU Preintegration and Error Model; III-D = Triggering and Multi-Crop Search;
III-E = Yaw-Residual Gate; III-F = UKF Fusion; III-G = Factor Graph and Loop Closure; IV = Results), or marked
"not in the paper" with the reason for the choice. A vehicle profile's sections load into these very classes
(config/profile.py, config/loading.py checks the `bounded` ranges). Lengths metres, angles radians, times s."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from taco_mav.core.fields import bounded
from taco_mav.core.gnss.params import GnssParams
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.wheel_params import WheelParams

__all__ = ["AnswerParams", "ErrorModelParams", "GateParams", "ImuParams", "LatencyParams", "LocaliserParams", "SmootherParams",
           "TriggerParams", "UkfParams"]


@dataclass(frozen=True)
class ImuParams:
    """IMU characteristics and preintegration settings."""

    # sigma_omega: gyro angle random walk, rad/sqrt(s) (Sec. III-B: "calibrated to the platform's IMU";
    # the paper gives no number). Default: 0.3 deg/sqrt(h), an automotive-grade MEMS gyro.
    gyro_arw: float = field(default=math.radians(0.3) / 60.0, metadata=bounded(0.0, 1.0))
    # Camera/filter frame rate, Hz: the UKF predicts on preintegrated increments at this rate (Sec. IV-A:
    # 10 Hz camera; Sec. III-F: process noise is per camera-rate frame).
    frame_rate_hz: float = field(default=10.0, metadata=bounded(0.5, 100.0, open_lo=True))
    # Corner frequency of the first-order high-pass applied to the forward acceleration before sigma_a is
    # taken (Sec. III-B names the filter, not its corner; 0.2 Hz keeps manoeuvres, drops the constant bias).
    accel_highpass_hz: float = field(default=0.2, metadata=bounded(0.0, 10.0, open_lo=True))
    # Ground vehicles rarely reverse; with False the integrated speed is clamped at zero (not in the paper).
    allow_reverse: bool = False
    # Longest IMU gap integrated as one step, s; longer gaps are integrated as this much (not in the paper).
    max_dt_s: float = field(default=0.5, metadata=bounded(0.0, 10.0, open_lo=True))
    # Time constant, s, of a first-order low-pass on the roll and pitch that take gravity off the forward
    # acceleration (not in the paper; 0: each sample's attitude, as the paper). Beside an autopilot whose EKF
    # fuses our output its attitude is not independent of us: on the IMU alone EKF3 tilts its pitch towards our
    # speed error (SITL's camera-fault flight, `pytest -m sitl -k camera_frozen`, docs/sitl.md: 0.29 deg std of
    # pitch on level ground; in a camera outage our speed 1.1 m/s slow after 12 s where the accelerometer alone
    # was 0.05 m/s off, and the rover sped to 4.8 m/s on a 3 m/s mission). The rover profiles set 30 s (that
    # flight's pitch std 0.29 -> 0.035 deg); the accel-bias state takes the slow rest, such as a grade the
    # low-pass has not caught up with.
    tilt_lowpass_s: float = field(default=0.0, metadata=bounded(0.0, 3600.0))


@dataclass(frozen=True)
class ErrorModelParams:
    """IMU error envelope, Sec. III-B, eq. (1) and the composite trigger value."""

    cross_k: float = field(default=3.0, metadata=bounded(0.0))  # 3-sigma inflation of d(T) sigma_w sqrt(T)
    along_k: float = field(default=0.5, metadata=bounded(0.0))  # 1/2 sigma_a(T) T^2
    divergence_k: float = field(default=0.03, metadata=bounded(0.0))  # floor 0.03 d_div


@dataclass(frozen=True)
class TriggerParams:
    """Dual trigger and five-point forward-biased search, Sec. III-D."""

    epsilon_m: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))  # fire when eps_IMU >= 1.0 m
    time_s: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))  # or >= 2.0 s since last fix
    forward_bias: bool = True  # ablation "no forward bias" sets False
    forward_bias_k: float = field(default=0.4, metadata=bounded(0.0))  # delta = min(0.4 eps, 15 m)
    forward_bias_cap_m: float = field(default=15.0, metadata=bounded(0.0))
    multi_crop: bool = True  # ablation "single crop" sets False (only the centre crop)
    cross_k: float = field(default=0.5, metadata=bounded(0.0))  # d = min(0.5 eps, 10 m)
    cross_cap_m: float = field(default=10.0, metadata=bounded(0.0))
    # A query unanswered after this long is dropped so a new one can be issued (not in the paper).
    query_timeout_s: float = field(default=5.0, metadata=bounded(0.0, open_lo=True))


@dataclass(frozen=True)
class GateParams:
    """Yaw-residual gate, Sec. III-E."""

    enabled: bool = True  # ablation "no yaw gate" sets False
    yaw_residual_max_rad: float = field(default=0.35, metadata=bounded(0.0, math.pi))  # |psi_res| > 0.35 rejects


@dataclass(frozen=True)
class AnswerParams:
    """What a matcher's answer must show before any mode may make a fix of it (core/answer_check.py; not in the
    paper, which fuses every answer with its weight mapped to a sigma). The defaults are the paper's: no decoys,
    every answer usable, one crop enough."""

    w_min: float = field(default=0.0, metadata=bounded(0.0, 1.0))  # answers weaker than this are not credible
    # Decoy crops per trigger (0-3: the centre crop turned by 90, 270 and 180 deg, in that order), whose in-gate
    # answers are the scene's chance level (cvgl/service.py). Real pairs (`taco-mav bench --only real`):
    # with 3, no answer of 96 on real imagery and none on another place's map passes a margin of 4, while every
    # rendered view of the synthetic pairs does (64 of 64; docs/matchers.md).
    decoys: int = field(default=0, metadata=bounded(0, 3))
    # The least log-odds log(w / (1 - w)) by which an answer must beat the decoys' (the classical matcher's w is a
    # logistic of its PSR with scale 0.5, so 4 = 2 PSR units: about two sidelobe standard deviations).
    decoy_margin: float = field(default=0.0, metadata=bounded(0.0, 50.0))
    # The least share of the crops that could give the chosen answer (agree_window_m) that must be credible and
    # agree with it (within agree_radius_m): a matcher that has found the camera finds it in every crop whose
    # search window holds it, so an answer only one or two of five crops give is as much the crop's as the place's (real pairs:
    # the three answers of 96 that beat the decoys were 28-46 m off, given by one or two crops; every synthetic
    # pair's right answer by five of five). 0: one crop is enough.
    min_agree_share: float = field(default=0.0, metadata=bounded(0.0, 1.0))
    # Answers within this of each other agree, m (as plus.consensus_radius_m); a decoy's answer this close to an
    # answer found the same place turned (a crossing looks alike a quarter turn round) and is not chance.
    agree_radius_m: float = field(default=3.0, metadata=bounded(0.0, open_lo=True))
    # The crops that could give an answer: those whose centre lies within this of it, m (the classical matcher
    # searches 30 m round a crop's centre; taco+'s recovery grid spaces crops 15 m apart, so 20 m holds the six
    # or seven nearest). With min_agree_share > 0 at least two of them must agree.
    agree_window_m: float = field(default=20.0, metadata=bounded(0.0, open_lo=True))


@dataclass(frozen=True)
class UkfParams:
    """3-state UKF with anisotropic CVGL noise, Sec. III-F."""

    alpha: float = field(default=1e-3, metadata=bounded(0.0, 1.0, open_lo=True))  # van der Merwe alpha
    beta: float = field(default=2.0, metadata=bounded(0.0))  # van der Merwe beta
    kappa: float = 0.0  # van der Merwe kappa
    # Process noise per camera-rate frame (scaled with dt / frame period): sigma_fwd = max(1.0, 2.0 eps) m,
    # sigma_lat = max(1.5, 0.3 eps) m, sigma_theta = 0.05 rad.
    sigma_fwd_min_m: float = field(default=1.0, metadata=bounded(0.0))
    sigma_fwd_k: float = field(default=2.0, metadata=bounded(0.0))
    sigma_lat_min_m: float = field(default=1.5, metadata=bounded(0.0))
    sigma_lat_k: float = field(default=0.3, metadata=bounded(0.0))
    sigma_theta_rad: float = field(default=0.05, metadata=bounded(0.0))
    # Per-fix measurement sigmas: sigma_fwd,w = clip(1.5 / w, 0.5, 8.0), sigma_lat,w = clip(3.0 / w, 1.0, 12.0).
    fix_fwd_num: float = field(default=1.5, metadata=bounded(0.0, open_lo=True))
    fix_fwd_min_m: float = field(default=0.5, metadata=bounded(0.0, open_lo=True))
    fix_fwd_max_m: float = field(default=8.0, metadata=bounded(0.0, open_lo=True))
    fix_lat_num: float = field(default=3.0, metadata=bounded(0.0, open_lo=True))
    fix_lat_min_m: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    fix_lat_max_m: float = field(default=12.0, metadata=bounded(0.0, open_lo=True))
    anisotropic: bool = True  # ablation "isotropic noise": both sigmas = their mean
    # Heading is supplied by the compass (Sec. III-B); we fuse it as a heading measurement with this 1-sigma
    # at every frame so the heading variance stays bounded (the paper states the source, not the sigma).
    compass_sigma_rad: float = field(default=0.05, metadata=bounded(0.0, open_lo=True))
    # Initial 1-sigma of position and heading at the start-up GNSS reading (not in the paper; the smoother's
    # origin prior uses 0.01, Sec. III-G).
    initial_sigma_xy_m: float = field(default=0.01, metadata=bounded(0.0, open_lo=True))
    initial_sigma_theta_rad: float = field(default=0.05, metadata=bounded(0.0, open_lo=True))


@dataclass(frozen=True)
class SmootherParams:
    """Pose2 factor graph with vetted loop closures, Sec. III-G."""

    enabled: bool = True  # ablation "UKF only" sets False
    origin_sigma: float = field(default=0.01, metadata=bounded(0.0, open_lo=True))
    nonholonomic_sigma_m: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    lc_max_chord_m: float = field(default=50.0, metadata=bounded(0.0))
    lc_min_frame_gap: int = field(default=30, metadata=bounded(1))
    lc_min_path_ratio: float = field(default=5.0, metadata=bounded(0.0))
    lc_sigma_floor_m: float = field(default=0.5, metadata=bounded(0.0, open_lo=True))
    lm_max_iterations: int = field(default=100, metadata=bounded(1))
    lm_relative_tolerance: float = field(default=1e-5, metadata=bounded(0.0, open_lo=True))
    savgol_window: int = field(default=15, metadata=bounded(0))  # 0 disables the Savitzky-Golay pass
    savgol_order: int = field(default=3, metadata=bounded(0))


@dataclass(frozen=True)
class LatencyParams:
    """Delayed fixes (not in the paper: it applies fixes as if current)."""

    # Apply each fix at its arrival as if it were current (the naive way) instead of at its capture time.
    apply_on_arrival: bool = False
    # How far back a fix may reach, s: filter states and increments for this long are kept.
    history_s: float = field(default=10.0, metadata=bounded(0.0, open_lo=True))


@dataclass(frozen=True)
class LocaliserParams:
    """Everything the Localiser takes (`config.localiser_params` builds it from a profile; the core never sees the
    Profile itself): the paper's sections, where the camera sits, the map's georeferencing error, taco+ (None =
    paper mode) and real GNSS."""

    imu: ImuParams = ImuParams()
    error_model: ErrorModelParams = ErrorModelParams()
    trigger: TriggerParams = TriggerParams()
    gate: GateParams = GateParams()
    answer: AnswerParams = AnswerParams()
    ukf: UkfParams = UkfParams()
    smoother: SmootherParams = SmootherParams()
    latency: LatencyParams = LatencyParams()
    # the camera's position relative to the vehicle reference point, body (forward, left) metres: the lever arm
    # that fix_position takes off every matcher answer (profile camera.position_frd_m; zero = camera at the point)
    camera_lever_fwd_left_m: tuple[float, float] = (0.0, 0.0)
    # the map's georeferencing 1-sigma per axis, m: taco+ then carries the map's offset as two filter states
    # (profile map.georef_sigma_m; 0: the map is exact, as in the paper)
    map_georef_sigma_m: float = 0.0
    # taco+ (not in the paper: docs/taco_plus.md): None = paper mode
    plus: PlusParams | None = None
    # real GNSS while it is honest, and the spoofing/jamming guard (not in the paper)
    gnss: GnssParams = GnssParams()
    # the wheel encoders (profile wheels: when enabled; taco+ fuses their speed); None: no wheels
    wheels: WheelParams | None = None
