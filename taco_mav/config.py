"""Vehicle profiles: frozen dataclasses with the paper's values as defaults, loaded from YAML.

Every TACO parameter is named here, defaulted to the value in `../shared/paper/TACO.tex`, and cited by
section ("Sec. III-B" = Methodology, IMU Preintegration and Error Model; III-D = Triggering and Multi-Crop
Search; III-E = Yaw-Residual Gate; III-F = UKF Fusion; III-G = Factor Graph and Loop Closure; IV = Results).
Values the paper does not give are marked "not in the paper" with the reason for our choice.

A profile YAML mirrors the nesting of `Profile`; any key it leaves out keeps its default. Unknown keys,
wrong types and out-of-range values raise `ConfigError` naming the file and the dotted key.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from taco_mav.errors import ConfigError


class Estimator(enum.Enum):
    """Estimator mode: the paper exactly, or our improvements (issue 7)."""

    PAPER = "paper"
    TACO_PLUS = "taco+"


def _rng(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False) -> dict[str, Any]:
    return {"range": (lo, hi, open_lo)}


@dataclass(frozen=True)
class ImuConfig:
    """IMU characteristics and preintegration settings."""

    # sigma_omega: gyro angle random walk, rad/sqrt(s) (Sec. III-B: "calibrated to the platform's IMU";
    # the paper gives no number). Default: 0.3 deg/sqrt(h), an automotive-grade MEMS gyro.
    gyro_arw: float = field(default=math.radians(0.3) / 60.0, metadata=_rng(0.0, 1.0))
    # Camera/filter frame rate, Hz: the UKF predicts on preintegrated increments at this rate (Sec. IV-A:
    # 10 Hz camera; Sec. III-F: process noise is per camera-rate frame).
    frame_rate_hz: float = field(default=10.0, metadata=_rng(0.5, 100.0, open_lo=True))
    # Corner frequency of the first-order high-pass applied to the forward acceleration before sigma_a is
    # taken (Sec. III-B names the filter, not its corner; 0.2 Hz keeps manoeuvres, drops the constant bias).
    accel_highpass_hz: float = field(default=0.2, metadata=_rng(0.0, 10.0, open_lo=True))
    # Ground vehicles rarely reverse; with False the integrated speed is clamped at zero (not in the paper).
    allow_reverse: bool = False
    # Longest IMU gap integrated as one step, s; longer gaps are integrated as this much (not in the paper).
    max_dt_s: float = field(default=0.5, metadata=_rng(0.0, 10.0, open_lo=True))


@dataclass(frozen=True)
class ErrorModelConfig:
    """IMU error envelope, Sec. III-B, eq. (1) and the composite trigger value."""

    cross_k: float = field(default=3.0, metadata=_rng(0.0))  # 3-sigma inflation of d(T) sigma_w sqrt(T)
    along_k: float = field(default=0.5, metadata=_rng(0.0))  # 1/2 sigma_a(T) T^2
    divergence_k: float = field(default=0.03, metadata=_rng(0.0))  # floor 0.03 d_div


@dataclass(frozen=True)
class TriggerConfig:
    """Dual trigger and five-point forward-biased search, Sec. III-D."""

    epsilon_m: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))  # fire when eps_IMU >= 1.0 m
    time_s: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))  # or >= 2.0 s since last fix
    forward_bias: bool = True  # ablation "no forward bias" sets False
    forward_bias_k: float = field(default=0.4, metadata=_rng(0.0))  # delta = min(0.4 eps, 15 m)
    forward_bias_cap_m: float = field(default=15.0, metadata=_rng(0.0))
    multi_crop: bool = True  # ablation "single crop" sets False (only the centre crop)
    cross_k: float = field(default=0.5, metadata=_rng(0.0))  # d = min(0.5 eps, 10 m)
    cross_cap_m: float = field(default=10.0, metadata=_rng(0.0))
    # A query unanswered after this long is dropped so a new one can be issued (not in the paper).
    query_timeout_s: float = field(default=5.0, metadata=_rng(0.0, open_lo=True))


@dataclass(frozen=True)
class GateConfig:
    """Yaw-residual gate, Sec. III-E."""

    enabled: bool = True  # ablation "no yaw gate" sets False
    yaw_residual_max_rad: float = field(default=0.35, metadata=_rng(0.0, math.pi))  # |psi_res| > 0.35 rejects


@dataclass(frozen=True)
class UkfConfig:
    """3-state UKF with anisotropic CVGL noise, Sec. III-F."""

    alpha: float = field(default=1e-3, metadata=_rng(0.0, 1.0, open_lo=True))  # van der Merwe alpha
    beta: float = field(default=2.0, metadata=_rng(0.0))  # van der Merwe beta
    kappa: float = 0.0  # van der Merwe kappa
    # Process noise per camera-rate frame (scaled with dt / frame period): sigma_fwd = max(1.0, 2.0 eps) m,
    # sigma_lat = max(1.5, 0.3 eps) m, sigma_theta = 0.05 rad.
    sigma_fwd_min_m: float = field(default=1.0, metadata=_rng(0.0))
    sigma_fwd_k: float = field(default=2.0, metadata=_rng(0.0))
    sigma_lat_min_m: float = field(default=1.5, metadata=_rng(0.0))
    sigma_lat_k: float = field(default=0.3, metadata=_rng(0.0))
    sigma_theta_rad: float = field(default=0.05, metadata=_rng(0.0))
    # Per-fix measurement sigmas: sigma_fwd,w = clip(1.5 / w, 0.5, 8.0), sigma_lat,w = clip(3.0 / w, 1.0, 12.0).
    fix_fwd_num: float = field(default=1.5, metadata=_rng(0.0, open_lo=True))
    fix_fwd_min_m: float = field(default=0.5, metadata=_rng(0.0, open_lo=True))
    fix_fwd_max_m: float = field(default=8.0, metadata=_rng(0.0, open_lo=True))
    fix_lat_num: float = field(default=3.0, metadata=_rng(0.0, open_lo=True))
    fix_lat_min_m: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))
    fix_lat_max_m: float = field(default=12.0, metadata=_rng(0.0, open_lo=True))
    anisotropic: bool = True  # ablation "isotropic noise": both sigmas = their mean
    # Heading is supplied by the compass (Sec. III-B); we fuse it as a heading measurement with this 1-sigma
    # at every frame so the heading variance stays bounded (the paper states the source, not the sigma).
    compass_sigma_rad: float = field(default=0.05, metadata=_rng(0.0, open_lo=True))
    # Initial 1-sigma of position and heading at the start-up GNSS reading (not in the paper; the smoother's
    # origin prior uses 0.01, Sec. III-G).
    initial_sigma_xy_m: float = field(default=0.01, metadata=_rng(0.0, open_lo=True))
    initial_sigma_theta_rad: float = field(default=0.05, metadata=_rng(0.0, open_lo=True))


@dataclass(frozen=True)
class SmootherConfig:
    """Pose2 factor graph with vetted loop closures, Sec. III-G."""

    enabled: bool = True  # ablation "UKF only" sets False
    origin_sigma: float = field(default=0.01, metadata=_rng(0.0, open_lo=True))
    nonholonomic_sigma_m: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))
    lc_max_chord_m: float = field(default=50.0, metadata=_rng(0.0))
    lc_min_frame_gap: int = field(default=30, metadata=_rng(1))
    lc_min_path_ratio: float = field(default=5.0, metadata=_rng(0.0))
    lc_sigma_floor_m: float = field(default=0.5, metadata=_rng(0.0, open_lo=True))
    lm_max_iterations: int = field(default=100, metadata=_rng(1))
    lm_relative_tolerance: float = field(default=1e-5, metadata=_rng(0.0, open_lo=True))
    savgol_window: int = field(default=15, metadata=_rng(0))  # 0 disables the Savitzky-Golay pass
    savgol_order: int = field(default=3, metadata=_rng(0))


@dataclass(frozen=True)
class PlusConfig:
    """taco+ (estimator: taco+; issue 7, not in the paper). Defaults were chosen on the synthetic worlds and
    checked on KITTI 04/05/07/09 (docs/taco_plus.md); every value is per second or per metre travelled."""

    # Process noise from the IMU's error growth (replaces Sec. III-F's sigma_fwd >= 1 m per frame).
    q_pos_mps: float = field(default=0.02, metadata=_rng(0.0))  # position random walk, m/sqrt(s)
    q_fwd_per_m: float = field(default=0.01, metadata=_rng(0.0))  # along-track 1-sigma per metre travelled
    q_lat_per_m: float = field(default=0.01, metadata=_rng(0.0))  # cross-track 1-sigma per metre travelled
    q_theta_rad: float = field(default=0.002, metadata=_rng(0.0))  # heading random walk, rad/sqrt(s)
    q_speed_mps: float = field(default=0.2, metadata=_rng(0.0))  # speed-error random walk, (m/s)/sqrt(s)
    # accel-bias random walk, (m/s^2)/sqrt(s): more than a bias instability, so b also absorbs the slowly varying
    # speed-error drift that 10 Hz integration of braking and slopes leaves (measured on KITTI 04-09 OXTS)
    q_bias_mps2: float = field(default=0.005, metadata=_rng(0.0))
    # Compass/AHRS heading bias as a state (first-order Gauss-Markov, std and correlation time); 0 disables.
    # The paper treats the compass as white noise (Sec. III-F); a correlated yaw error bends the track between
    # fixes, and consecutive fixes make it observable.
    compass_bias_sigma_rad: float = field(default=0.01, metadata=_rng(0.0))
    compass_bias_tau_s: float = field(default=60.0, metadata=_rng(0.0, open_lo=True))
    initial_speed_sigma_mps: float = field(default=0.3, metadata=_rng(0.0, open_lo=True))
    initial_bias_sigma_mps2: float = field(default=0.05, metadata=_rng(0.0, open_lo=True))
    # Zero-velocity updates when the IMU says the vehicle stands still.
    zupt: bool = True
    zupt_sigma_mps: float = field(default=0.02, metadata=_rng(0.0, open_lo=True))
    zupt_window_s: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))
    zupt_gyro_max_rps: float = field(default=0.02, metadata=_rng(0.0))
    zupt_accel_std_max_mps2: float = field(default=0.05, metadata=_rng(0.0))
    zupt_speed_max_mps: float = field(default=0.5, metadata=_rng(0.0))
    # ... and not while the mean forward acceleration (less the bias estimate) exceeds this, m/s^2: a smooth
    # steady acceleration has no spread (SITL's rover pulling away was taken for a stop).
    zupt_accel_mean_max_mps2: float = field(default=0.15, metadata=_rng(0.0))
    # ... and not while the autopilot drives (armed, throttle output), a command at most this old, s.
    drive_command_timeout_s: float = field(default=1.0, metadata=_rng(0.0))
    # ... and only for a speed the IMU may have lost since the speed was last observed (a fix, a stop): this
    # 1-sigma forward-acceleration error (m/s^2; a MEMS AHRS's 0.3 deg of pitch is 0.05) plus the bias
    # state's, integrated over the time since, 3 sigma, plus zupt_speed_max_mps. Also the IMU-only track's.
    imu_accel_sigma_mps2: float = field(default=0.05, metadata=_rng(0.0))
    # Speed from the camera (issue 19, not in the paper): ground-plane motion between two frames 0.3 s apart,
    # every 0.5 s (link/motion.py), as a speed measurement; camera_speed_scale_sigma: its 1-sigma scale error
    # (a 3 cm error in a 1 m mount height is 3 %), beside the correlation's own. Needs a camera.
    camera_speed: bool = True
    camera_speed_scale_sigma: float = field(default=0.03, metadata=_rng(0.0))
    # a measurement moving sideways more than this (m) plus 30 % of its forward motion is refused: a wheeled
    # vehicle barely slips, so it is a heading change the compass got wrong (SITL: an AHRS settling at boot)
    camera_lateral_max_m: float = field(default=0.15, metadata=_rng(0.0))
    # Closed-loop safety guard (issue 19, core/imu_check.py): the estimate against the IMU-only track since the
    # last accepted fix; a disagreement beyond guard_k combined sigmas (and guard_floor_m) keeps the reported
    # variance at least the disagreement squared and holds zero-velocity updates off; guard_gate_misses
    # consecutive innovation-gate rejections widen the position uncertainty by half the disagreement.
    guard: bool = True
    guard_k: float = field(default=3.0, metadata=_rng(0.0, open_lo=True))
    guard_floor_m: float = field(default=2.0, metadata=_rng(0.0))
    guard_zupt_holdoff_s: float = field(default=10.0, metadata=_rng(0.0))
    guard_gate_misses: int = field(default=2, metadata=_rng(1))
    # Covariance trigger: a fix when the filter's 1-sigma reaches this (or after trigger_time_s moving).
    trigger_sigma_m: float = field(default=3.0, metadata=_rng(0.0, open_lo=True))
    trigger_time_s: float = field(default=10.0, metadata=_rng(0.0, open_lo=True))
    cross_k: float = field(default=2.0, metadata=_rng(0.0))  # cross arm = clip(k sigma_h, min, max)
    cross_min_m: float = field(default=1.0, metadata=_rng(0.0))
    cross_max_m: float = field(default=10.0, metadata=_rng(0.0))
    # Innovation gate (beside the yaw gate) and consensus over the crops.
    chi2_gate: float = field(default=13.82, metadata=_rng(0.0, open_lo=True))  # 2 dof, 99.9 %
    # the gate for an answer that no other crop of the trigger agrees with (consensus support 1), 2 dof, 95 %
    chi2_gate_single: float = field(default=5.99, metadata=_rng(0.0, open_lo=True))
    consensus_radius_m: float = field(default=3.0, metadata=_rng(0.0))
    w_min: float = field(default=0.2, metadata=_rng(0.0, 1.0))  # weaker answers count as misses
    # Adaptive fix noise: the paper's w -> sigma mapping (Sec. III-F) times a scale learnt from the innovations of
    # accepted fixes (covariance matching), clipped to [fix_scale_min, fix_scale_max]; the chi-square gate keeps
    # the unscaled mapping. fix_scale_window: fixes in the exponential average.
    adaptive_fix_noise: bool = True
    fix_scale_min: float = field(default=0.3, metadata=_rng(0.0, open_lo=True))
    fix_scale_max: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))
    fix_scale_window: int = field(default=10, metadata=_rng(1))
    # Loss of lock and recovery.
    capture_radius_m: float = field(default=20.0, metadata=_rng(0.0, open_lo=True))  # FG2's, Sec. III-D
    lost_after: int = field(default=4, metadata=_rng(1))  # consecutive triggers without an accepted fix
    lost_after_s: float = field(default=8.0, metadata=_rng(0.0))  # ... over at least this long since the last one
    lost_sigma_min_m: float = field(default=10.0, metadata=_rng(0.0))
    grid_spacing_m: float = field(default=15.0, metadata=_rng(0.0, open_lo=True))
    grid_max_rings: int = field(default=4, metadata=_rng(1, 10))
    recover_interval_s: float = field(default=0.5, metadata=_rng(0.0))  # also the least spacing of triggers
    recover_w_min: float = field(default=0.5, metadata=_rng(0.0, 1.0))
    confirm_fixes: int = field(default=3, metadata=_rng(0))


@dataclass(frozen=True)
class GnssConfig:
    """Real GNSS while it is honest, and the spoofing/jamming guard (issue 14, not in the paper: it takes one
    GNSS reading at start-up). Both estimators take `Localiser.add_gnss`: taco+ fuses position, speed and course
    (calibrating speed error, accelerometer and compass bias), paper mode re-anchors on it. The guard tests each
    reading against the filter's state `reference_lag_s` earlier carried forward by IMU dead reckoning alone
    (core/gnss_guard.py). Defaults were set on synthetic drives with the automotive IMU preset (the pessimistic
    one, docs/taco_plus.md) and the simulator's receiver (white sigma_h / 2, Gauss-Markov bias 0.87 sigma_h,
    tau 60 s): honest 1.5 m readings accepted 100 % of the time, velocity-dragging spoofs caught in 1-2 s."""

    enabled: bool = True  # False: add_gnss ignores every reading
    # Measurements. A receiver's h_acc below 0.5 m is taken as 0.5 (an RTK fix would otherwise pin the filter).
    sigma_h_min_m: float = field(default=0.5, metadata=_rng(0.0, open_lo=True))
    sigma_v_min_mps: float = field(default=0.1, metadata=_rng(0.0, open_lo=True))  # floor on vel_acc
    # Speed and course are fused above this ground speed (course is noise when standing; 1 m/s, issue 14).
    min_speed_mps: float = field(default=1.0, metadata=_rng(0.0))
    # Course as a heading measurement: 1-sigma = max(this, vel_acc / speed); 0.03 rad covers a ground vehicle's
    # side slip in ordinary turns and the antenna's lever arm.
    course_sigma_min_rad: float = field(default=0.03, metadata=_rng(0.0, open_lo=True))
    max_age_s: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))  # older (or newer) than the IMU: stale
    # A reading moves the estimate this late (rewind and replay, as a late camera fix), so the guard has seen
    # the readings after it: 1 s lets the velocity test (which catches a velocity-dragging spoof in 1-2 s) reject
    # before the first dragged reading is fused, and costs the reported accuracy little (1.4 m 1-sigma on the
    # synthetic drives against 1.3 m undelayed; 2 s: 4 m with the synthetic profile's loose speed model).
    fuse_delay_s: float = field(default=1.0, metadata=_rng(0.0))
    fuse_interval_s: float = field(default=0.5, metadata=_rng(0.0))  # batches: one rewind and replay each
    # The receiver's error model: white noise of white_fraction x its reported sigma, the rest a wandering bias
    # (first-order Gauss-Markov, correlation time bias_tau_s), as real receivers wander (multipath, atmosphere)
    # and as the simulator models them (white sigma / 2, tau 60 s).
    white_fraction: float = field(default=0.5, metadata=_rng(0.0, 1.0, open_lo=True))
    bias_tau_s: float = field(default=60.0, metadata=_rng(0.0, open_lo=True))
    # The shadow references: the filter's state this long before a reading (in the frame history, so at most
    # latency.history_s), carried forward by dead reckoning. 7 s: a 0.5 m/s drag has moved 3.5 m while the
    # automotive IMU's dead reckoning has drifted ~0.6 m and the receiver's bias ~0.6 m (1 sigma each).
    reference_lag_s: float = field(default=7.0, metadata=_rng(0.0, open_lo=True))
    # ... 3 s for the velocity test: a speed error grows with the shadow's age (automotive ~0.05 m/s per s).
    velocity_lag_s: float = field(default=3.0, metadata=_rng(0.0, open_lo=True))
    # Dead-reckoning error growth of a shadow beyond the estimator's own uncertainty at its anchor, from shadows
    # of taco+ on synthetic drives with the automotive preset after GNSS calibration (error at 7 s: along 0.6 m,
    # across 0.45 m RMS): speed 0.05 m/s, acceleration 0.03 m/s^2, heading 0.012 rad (times the distance),
    # position random walk 0.05 m/sqrt(s); an estimator without a bias state (paper mode) also leaves the
    # accelerometer bias, 0.05 m/s^2 (3 mg turn-on bias and 0.2 deg of AHRS tilt, 1 sigma).
    dr_speed_sigma_mps: float = field(default=0.05, metadata=_rng(0.0))
    dr_accel_sigma_mps2: float = field(default=0.03, metadata=_rng(0.0))
    dr_heading_sigma_rad: float = field(default=0.012, metadata=_rng(0.0))
    dr_pos_rw_mps: float = field(default=0.05, metadata=_rng(0.0))
    dr_accel_bias_sigma_mps2: float = field(default=0.05, metadata=_rng(0.0))
    # The shadows' modelled growth (the drift above plus the estimator's own speed, bias and heading
    # uncertainty, which taco+ keeps loose on purpose) is scaled by what accepted readings show (covariance
    # matching over dr_scale_n readings, clipped to [dr_scale_min, dr_scale_max]; 1 until then), and by at least
    # held_scale_min while the receiver is held off (the shadow then ages past the lag the scale was learnt at).
    dr_scale_min: float = field(default=0.1, metadata=_rng(0.0, open_lo=True))
    dr_scale_max: float = field(default=4.0, metadata=_rng(0.0, open_lo=True))
    dr_scale_n: int = field(default=200, metadata=_rng(1))
    held_scale_min: float = field(default=0.3, metadata=_rng(0.0))
    # Tests. Mean NIS over window_s against chi2(2 N, 1 - window_alpha) / N, N one reading per window_corr_s
    # (the readings' errors are correlated); mean innovation of the last drift_window_s (position, and velocity)
    # against chi2(2 dof) drift_gate = 99.9 %; one reading against the filter: hard_gate = 99.99 %.
    window_s: float = field(default=10.0, metadata=_rng(0.0, open_lo=True))
    window_alpha: float = field(default=1e-4, metadata=_rng(0.0, 0.5, open_lo=True))
    window_min_n: int = field(default=5, metadata=_rng(1))
    window_corr_s: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))
    drift_window_s: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))
    drift_gate: float = field(default=13.82, metadata=_rng(0.0, open_lo=True))
    hard_gate: float = field(default=18.42, metadata=_rng(0.0, open_lo=True))
    # The first reading after a loss or a rejection is fused only if the update moves the estimate by at most
    # 3 sigma of its covariance ((3 sigma)^2 = 9), so the output never jumps further at a hand-over.
    jump_gate: float = field(default=9.0, metadata=_rng(0.0, open_lo=True))
    gap_s: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))  # no reading this long: the receiver was lost
    # A rejected receiver is used again after every test has passed, with the drift and velocity statistics
    # below suspect_gate (2 dof, 95 %), for reaccept_s (issue 14: "agrees again for a sustained period").
    reaccept_s: float = field(default=10.0, metadata=_rng(0.0))
    suspect_gate: float = field(default=5.99, metadata=_rng(0.0, open_lo=True))
    # Camera fixes cross-check the receiver: one every camera_interval_s while it is healthy (the camera's duty
    # drops from the trigger's), one after camera_check_s when the guard is suspicious; camera_disagree_n fixes
    # in a row beyond camera_gate (2 dof, 99.9 %) of their combined covariance (camera, the readings within
    # camera_match_s averaged, the receiver's bias) reject the receiver.
    camera_interval_s: float = field(default=20.0, metadata=_rng(0.0))
    camera_check_s: float = field(default=3.0, metadata=_rng(0.0))
    camera_gate: float = field(default=13.82, metadata=_rng(0.0, open_lo=True))
    camera_disagree_n: int = field(default=2, metadata=_rng(1))
    camera_match_s: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))


@dataclass(frozen=True)
class LatencyConfig:
    """Delayed fixes (not in the paper: it applies fixes as if current)."""

    # Apply each fix at its arrival as if it were current (the naive way) instead of at its capture time.
    apply_on_arrival: bool = False
    # How far back a fix may reach, s: filter states and increments for this long are kept.
    history_s: float = field(default=10.0, metadata=_rng(0.0, open_lo=True))


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera looking forward from the vehicle. Defaults: KITTI image_02 (rectified P2)."""

    width_px: int = field(default=1242, metadata=_rng(1))
    height_px: int = field(default=375, metadata=_rng(1))
    fx: float = field(default=721.5377, metadata=_rng(0.0, open_lo=True))
    fy: float = field(default=721.5377, metadata=_rng(0.0, open_lo=True))
    cx: float = 609.5593
    cy: float = 172.854
    mount_height_m: float = field(default=1.65, metadata=_rng(0.0, open_lo=True))  # KITTI cameras: 1.65 m
    pitch_rad: float = field(default=0.0, metadata=_rng(-1.0, 1.0))  # positive = looking down
    # Lens calibration file (OpenCV FileStorage or ROS camera_info YAML, relative to the profile's folder; written
    # by `taco-mav calibrate`). With it frames are undistorted before the matcher and fx, fy, cx, cy, width_px,
    # height_px become that undistorted pinhole model (docs/camera.md); "" = frames are already pinhole.
    calibration: str = ""


@dataclass(frozen=True)
class MapConfig:
    """Satellite crops handed to the matcher (Sec. III-C)."""

    crop_size_px: int = field(default=512, metadata=_rng(16, 4096))
    # Mosaic resolution expected by the matcher, m/px; crops are resampled to it (zoom 19: ~0.3 m/px at
    # Karlsruhe's latitude, Sec. III-C; FG2's KITTI crops are ~0.2 m/px).
    crop_m_per_px: float = field(default=0.2, metadata=_rng(0.0, open_lo=True))
    # A crop with a smaller share of on-map pixels raises OffMapError; above it, off-map pixels are zero and
    # Crop.valid_fraction says how many were on the map (not in the paper).
    min_valid_fraction: float = field(default=0.9, metadata=_rng(0.0, 1.0))
    # Mosaics up to this size (decoded RGBA, MB) are read into memory at open; larger ones are read in cached
    # 256 px blocks (not in the paper).
    in_memory_max_mb: float = field(default=1024.0, metadata=_rng(0.0))
    # A matcher call running longer (wall s) is cancelled, counted, and its worker replaced.
    matcher_timeout_s: float = field(default=10.0, metadata=_rng(0.0, open_lo=True))


@dataclass(frozen=True)
class ClassicalMatcherConfig:
    """Classical matcher: inverse perspective mapping + FFT correlation (CPU)."""

    bev_size_px: int = field(default=256, metadata=_rng(16, 2048))
    # Matching resolution, m/px (0.6: 0.14 m median error at ~20 ms per five-crop trigger; see docs/matchers.md).
    bev_m_per_px: float = field(default=0.6, metadata=_rng(0.0, open_lo=True))
    max_range_m: float = field(default=40.0, metadata=_rng(1.0))
    rotation_range_rad: float = field(default=math.radians(10.0), metadata=_rng(0.0, math.pi))
    # Rotation grid step; the best grid angle is refined at +-step/2, +-step/4 and by a parabola.
    rotation_step_rad: float = field(default=math.radians(4.0), metadata=_rng(0.0, math.pi, open_lo=True))
    # w = 1 / (1 + exp(-(PSR - psr_at_half_weight) / psr_logistic_scale)), calibrated on the synthetic world and
    # the bench mosaic (taco_mav/cvgl/classical.py has the measurements).
    psr_at_half_weight: float = field(default=6.5, metadata=_rng(0.0, open_lo=True))
    psr_logistic_scale: float = field(default=0.5, metadata=_rng(0.0, open_lo=True))
    # Vehicle positions searched: within this many metres of the crop centre along each crop axis.
    search_radius_m: float = field(default=30.0, metadata=_rng(1.0))
    # Shifts where the template overlaps the valid crop by less than this share of its mask are not scored.
    min_overlap: float = field(default=0.6, metadata=_rng(0.0, 1.0, open_lo=True))
    # Local contrast normalisation (both images): Gaussian sigma of the local mean/std, metres.
    lcn_sigma_m: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))
    # Sidelobe for the peak-to-sidelobe ratio: the score map outside this radius around the peak, metres.
    psr_exclusion_m: float = field(default=2.0, metadata=_rng(0.0))


@dataclass(frozen=True)
class EmulatorConfig:
    """FG2-statistics emulator (a statistical model of FG2 on KITTI, not a matcher)."""

    capture_radius_m: float = field(default=20.0, metadata=_rng(0.0, open_lo=True))  # Sec. III-D
    median_error_m: float = field(default=0.51, metadata=_rng(0.0, open_lo=True))  # FG2 KITTI same-area
    mean_error_m: float = field(default=0.75, metadata=_rng(0.0, open_lo=True))
    cross_area_median_error_m: float = field(default=4.15, metadata=_rng(0.0, open_lo=True))  # cross-area
    cross_area_mean_error_m: float = field(default=7.31, metadata=_rng(0.0, open_lo=True))
    cross_area_sequences: tuple[str, ...] = ("00", "06")  # Sec. IV-A
    yaw_noise_rad: float = field(default=0.03, metadata=_rng(0.0))
    symmetric_lock_rate: float = field(default=0.03, metadata=_rng(0.0, 1.0))
    silent_outlier_rate: float = field(default=0.01, metadata=_rng(0.0, 1.0))
    seed: int = 0
    # Not in the paper (emulator shape, see docs/matchers.md): error direction is drawn with lateral/forward
    # spread 2:1 (Sec. III-F's sigma ratio); w = clip(exp(-err / weight_scale_m) + N(0, weight_noise)).
    lateral_to_forward: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))
    weight_scale_m: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))
    weight_noise: float = field(default=0.05, metadata=_rng(0.0))
    outlier_min_error_m: float = field(default=5.0, metadata=_rng(0.0))  # silent outliers: U(this, capture)
    miss_weight_max: float = field(default=0.15, metadata=_rng(0.0, 1.0, open_lo=True))  # outside capture radius


@dataclass(frozen=True)
class Fg2Config:
    """FG2 adapter (extra `fg2`): user-provided checkout and checkpoint."""

    checkout: str = ""
    checkpoint: str = ""
    device: str = "auto"  # "auto", "cpu" or "cuda"
    fp16: bool = True  # autocast on CUDA (Sec. IV-D)
    # "module:function" building the model from (checkout, checkpoint, device); imported with the checkout on
    # sys.path. The default shim checks the published FG2 layout (see docs/matchers.md).
    entry: str = "taco_mav.cvgl.fg2_shim:build_model"


@dataclass(frozen=True)
class LinkConfig:
    """MAVLink link to the autopilot (the daemon's inputs; see docs/ardupilot.md)."""

    # Our system id; 0 = take the autopilot's (the usual choice for a companion computer on the vehicle).
    sysid: int = field(default=0, metadata=_rng(0, 255))
    compid: int = field(default=191, metadata=_rng(1, 255))  # MAV_COMP_ID_ONBOARD_COMPUTER
    # Autopilot system id to listen to; 0 = the first HEARTBEAT from an autopilot component.
    target_sysid: int = field(default=0, metadata=_rng(0, 255))
    baud: int = field(default=921600, metadata=_rng(1200))  # serial links only (a "path:baud" CONN overrides)
    # IMU message to use: "auto" (first seen of HIGHRES_IMU, RAW_IMU, SCALED_IMU, SCALED_IMU2, SCALED_IMU3),
    # or one of those names.
    imu_message: str = "auto"
    imu_rate_hz: float = field(default=50.0, metadata=_rng(1.0, 400.0))  # requested IMU and ATTITUDE rate
    attitude_rate_hz: float = field(default=50.0, metadata=_rng(1.0, 400.0))
    request_rates: bool = True  # send SET_MESSAGE_INTERVAL (fallback REQUEST_DATA_STREAM) at start-up
    heartbeat_hz: float = field(default=1.0, metadata=_rng(0.2, 10.0))
    timesync_hz: float = field(default=1.0, metadata=_rng(0.0, 10.0))  # TIMESYNC requests; 0 disables
    # Autopilot time stepping back by more than this is a reboot: the estimator is re-anchored.
    reboot_backstep_s: float = field(default=1.0, metadata=_rng(0.0, open_lo=True))
    # Nothing from the autopilot for this long (companion clock, s) is a lost link: event + STATUSTEXT later.
    timeout_s: float = field(default=3.0, metadata=_rng(0.0, open_lo=True))
    check_params: bool = True  # read GPS1_TYPE / GPS_TYPE at start-up and warn unless 14 (ArduPilot)


@dataclass(frozen=True)
class OutputConfig:
    """What the daemon sends back (GPS_INPUT for ArduPilot; GLOBAL_POSITION_SENSOR or ODOMETRY for PX4)."""

    # Any of "gps_input", "global_position_sensor", "odometry".
    messages: tuple[str, ...] = ("gps_input",)
    rate_hz: float = field(default=5.0, metadata=_rng(1.0, 20.0))  # steady, independent of fixes
    gps_id: int = field(default=0, metadata=_rng(0, 9))  # zero-based GPS instance (GPS1 = 0)
    # Virtual satellite count (there are no satellites; EKF3 wants >= 6).
    satellites_visible: int = field(default=10, metadata=_rng(0, 255))
    # HDOP = horiz_accuracy / hdop_uere_m, clipped to [hdop_min, 99.99]; 2.0 maps EKF3's 5 m gate to HDOP 2.5.
    hdop_uere_m: float = field(default=2.0, metadata=_rng(0.0, open_lo=True))
    hdop_min: float = field(default=0.5, metadata=_rng(0.0, open_lo=True))
    # Reported speed accuracy, m/s: max(floor, fraction * speed) (the filter carries no speed covariance).
    speed_accuracy_floor_mps: float = field(default=0.3, metadata=_rng(0.0, open_lo=True))
    speed_accuracy_fraction: float = field(default=0.05, metadata=_rng(0.0))
    # fix_type 3 while sigma_h <= degrade_accuracy_m; above it fix_type 1 until sigma_h <= recover_accuracy_m.
    degrade_accuracy_m: float = field(default=10.0, metadata=_rng(0.0, open_lo=True))
    recover_accuracy_m: float = field(default=8.0, metadata=_rng(0.0, open_lo=True))
    stall_s: float = field(default=0.5, metadata=_rng(0.0, open_lo=True))  # no IMU this long: fix_type 1
    vertical_accuracy_m: float = field(default=5.0, metadata=_rng(0.0, open_lo=True))  # reported epv (flat ground)
    send_yaw: bool = True  # GPS_INPUT.yaw from the compass heading (36000 = north)
    leap_seconds: int = field(default=18, metadata=_rng(0, 60))  # GPS - UTC for time_week/time_week_ms
    statustext_interval_s: float = field(default=5.0, metadata=_rng(0.0))  # rate limit of fix STATUSTEXTs
    # GLOBAL_POSITION_SENSOR target (PX4): 0 = the autopilot's sysid / broadcast component.
    gps_sensor_id: int = field(default=0, metadata=_rng(0, 255))


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


_MATCHERS = ("classical", "emulator", "fg2")


def _convert(value: Any, tp: Any, where: str) -> Any:
    """Check and convert one YAML value against a type annotation; `where` names file and key."""
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return _build(tp, value, where)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(value, inner[0], where)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(value)
        except ValueError:
            allowed = ", ".join(repr(m.value) for m in tp)
            raise ConfigError(f"{where}: {value!r} is not one of {allowed}") from None
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        (elem, _ellipsis) = typing.get_args(tp)
        return tuple(_convert(v, elem, f"{where}[{i}]") for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, (str, int)) or isinstance(value, bool):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return str(value)
    raise ConfigError(f"{where}: unsupported type {tp!r}")  # pragma: no cover - a bug in this module


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        key_where = f"{where}.{key}" if not where.endswith(":") else f"{where} {key}"
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"{key_where}: unknown key (known: {known})")
        converted = _convert(value, hints[key], key_where)
        lo, hi, open_lo = fields[key].metadata.get("range", (None, None, False))
        if isinstance(converted, (int, float)) and not isinstance(converted, bool):
            if lo is not None and (converted < lo or (open_lo and converted == lo)):
                raise ConfigError(f"{key_where}: {converted} is out of range (must be {'>' if open_lo else '>='} {lo})")
            if hi is not None and converted > hi:
                raise ConfigError(f"{key_where}: {converted} is out of range (must be <= {hi})")
        kwargs[key] = converted
    return cls(**kwargs)


def profile_from_dict(data: dict[str, Any], source: str = "<dict>", base_dir: Path | None = None) -> Profile:
    """Build a Profile from a nested mapping; `source` names the file in error messages; base_dir: the folder
    relative paths in it are taken from (the profile's; default the working directory)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a profile must be a mapping at the top level")
    profile = _build(Profile, data, f"{source}:")
    if profile.matcher not in _MATCHERS:
        raise ConfigError(f"{source}: matcher: {profile.matcher!r} is not one of {', '.join(_MATCHERS)}")
    if profile.camera.calibration:
        from taco_mav.camera_calibration import resolve_calibration

        camera = resolve_calibration(profile.camera, data.get("camera") or {}, base_dir, f"{source}:")
        profile = dataclasses.replace(profile, camera=camera)
    return profile


PROFILE_DIR = Path(__file__).resolve().parent.parent / "vehicle_profiles"


def resolve_profile_path(name_or_path: str | Path) -> Path:
    """A path as given, or a bare name looked up in ./vehicle_profiles then the installed profiles."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ConfigError(f"{path}: profile file not found")
        return path
    for folder in (Path.cwd() / "vehicle_profiles", PROFILE_DIR):
        candidate = folder / f"{name_or_path}.yaml"
        if candidate.is_file():
            return candidate
    raise ConfigError(f"{name_or_path}: no such profile (looked for {name_or_path}.yaml in ./vehicle_profiles and {PROFILE_DIR})")


def load_profile(name_or_path: str | Path) -> Profile:
    """Load a vehicle profile by path or by name; errors name the file and the key."""
    path = resolve_profile_path(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path}: not valid YAML ({where}{problem})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    return profile_from_dict(data, str(path), base_dir=path.resolve().parent)


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
        plus=(PlusParams(**{f.name: getattr(profile.plus, f.name) for f in dataclasses.fields(PlusConfig)})
              if profile.estimator is Estimator.TACO_PLUS else None),
    )
