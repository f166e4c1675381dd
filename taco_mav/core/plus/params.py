"""taco+'s parameters (estimator: taco+; not in the paper): the one definition, its
defaults and where each comes from. A profile's `plus:` section loads into it (config/loading.py); the core's
taco+ parts read it (core/plus/: mode.py, noise.py, lock.py, ...). Lengths metres, angles radians, times
seconds, rates per second or per metre travelled."""

from __future__ import annotations

from dataclasses import dataclass, field

from taco_mav.core.fields import bounded

__all__ = ["PlusParams"]


@dataclass(frozen=True)
class PlusParams:
    """taco+ (estimator: taco+; not in the paper). Defaults were chosen on the synthetic worlds and
    checked on KITTI 04/05/07/09 (docs/taco_plus.md); every value is per second or per metre travelled."""

    # Process noise from the IMU's error growth (replaces Sec. III-F's sigma_fwd >= 1 m per frame).
    q_pos_mps: float = field(default=0.02, metadata=bounded(0.0))  # position random walk, m/sqrt(s)
    q_fwd_per_m: float = field(default=0.01, metadata=bounded(0.0))  # along-track 1-sigma per metre travelled
    q_lat_per_m: float = field(default=0.01, metadata=bounded(0.0))  # cross-track 1-sigma per metre travelled
    q_theta_rad: float = field(default=0.002, metadata=bounded(0.0))  # heading random walk, rad/sqrt(s)
    q_speed_mps: float = field(default=0.2, metadata=bounded(0.0))  # speed-error random walk, (m/s)/sqrt(s)
    # accel-bias random walk, (m/s^2)/sqrt(s): more than a bias instability, so b also absorbs the slowly varying
    # speed-error drift that 10 Hz integration of braking and slopes leaves (measured on KITTI 04-09 OXTS)
    q_bias_mps2: float = field(default=0.005, metadata=bounded(0.0))
    # Compass/AHRS heading bias as a state (first-order Gauss-Markov, std and correlation time); 0 disables.
    # The paper treats the compass as white noise (Sec. III-F); a correlated yaw error bends the track between
    # fixes, and consecutive fixes make it observable.
    compass_bias_sigma_rad: float = field(default=0.01, metadata=bounded(0.0))
    compass_bias_tau_s: float = field(default=60.0, metadata=bounded(0.0, open_lo=True))
    # The paper uses the answer's rotation only to gate it (Sec. III-E): 0 keeps it so. > 0: an accepted fix also
    # measures the true heading at its capture (the query's heading + the answer's yaw residual) with this 1-sigma,
    # rad, which makes an AHRS's heading error observable at once (PX4 SIH: 4-7 deg, docs/px4.md).
    fix_yaw_sigma_rad: float = field(default=0.0, metadata=bounded(0.0))
    # The paper's heading is the compass (the AHRS yaw) sample by sample (Sec. III-B). True: the heading between
    # frames integrates the gyro and the compass is fused as a slow reference (ukf.compass_sigma_rad): an AHRS
    # whose yaw lags real turns (PX4 SIH's EKF2: -4 deg for a -19 deg turn the gyro and truth agree on, docs/px4.md)
    # then bends no track.
    gyro_heading: bool = False
    initial_speed_sigma_mps: float = field(default=0.3, metadata=bounded(0.0, open_lo=True))
    initial_bias_sigma_mps2: float = field(default=0.05, metadata=bounded(0.0, open_lo=True))
    # Zero-velocity updates when the IMU says the vehicle stands still.
    zupt: bool = True
    zupt_sigma_mps: float = field(default=0.02, metadata=bounded(0.0, open_lo=True))
    zupt_window_s: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    zupt_gyro_max_rps: float = field(default=0.02, metadata=bounded(0.0))
    zupt_accel_std_max_mps2: float = field(default=0.05, metadata=bounded(0.0))
    zupt_speed_max_mps: float = field(default=0.5, metadata=bounded(0.0))
    # ... and not while the mean forward acceleration (less the bias estimate) exceeds this, m/s^2: a smooth
    # steady acceleration has no spread (SITL's rover pulling away was taken for a stop).
    zupt_accel_mean_max_mps2: float = field(default=0.15, metadata=bounded(0.0))
    # ... and not while the autopilot drives (armed, throttle output), a command at most this old, s.
    drive_command_timeout_s: float = field(default=1.0, metadata=bounded(0.0))
    # ... and only for a speed the IMU may have lost since the speed was last observed (a fix, a stop): this
    # 1-sigma forward-acceleration error (m/s^2; a MEMS AHRS's 0.3 deg of pitch is 0.05) plus the bias
    # state's, integrated over the time since, 3 sigma, plus zupt_speed_max_mps. Also the IMU-only track's.
    imu_accel_sigma_mps2: float = field(default=0.05, metadata=bounded(0.0))
    # Speed from the camera (not in the paper): ground-plane motion between two frames 0.3 s apart,
    # every 0.5 s (daemon/motion.py), as a speed measurement; camera_speed_scale_sigma: its 1-sigma scale error
    # (a 3 cm error in a 1 m mount height is 3 %), beside the correlation's own. Needs a camera.
    camera_speed: bool = True
    camera_speed_scale_sigma: float = field(default=0.03, metadata=bounded(0.0))
    # a measurement moving sideways more than this (m) plus 30 % of its forward motion is refused: a wheeled
    # vehicle barely slips, so it is a heading change the compass got wrong (SITL: an AHRS settling at boot)
    camera_lateral_max_m: float = field(default=0.15, metadata=bounded(0.0))
    # Closed-loop safety guard (core/plus/imu_check.py): the estimate against the IMU-only track since the
    # last accepted fix; a disagreement beyond guard_k combined sigmas (and guard_floor_m) keeps the reported
    # variance at least the disagreement squared and holds zero-velocity updates off; guard_gate_misses
    # consecutive innovation-gate rejections widen the position uncertainty by half the disagreement, when they
    # agree and each has a match weight w of at least guard_w_min (0: any w). A matcher's low-w answers that
    # land elsewhere are its chance peaks on a repetitive street, not evidence that the estimate is off.
    guard: bool = True
    guard_k: float = field(default=3.0, metadata=bounded(0.0, open_lo=True))
    guard_floor_m: float = field(default=2.0, metadata=bounded(0.0))
    guard_zupt_holdoff_s: float = field(default=10.0, metadata=bounded(0.0))
    guard_gate_misses: int = field(default=2, metadata=bounded(1))
    guard_w_min: float = field(default=0.0, metadata=bounded(0.0, 1.0))
    # Covariance trigger: a fix when the filter's 1-sigma reaches this (or after trigger_time_s moving).
    trigger_sigma_m: float = field(default=3.0, metadata=bounded(0.0, open_lo=True))
    trigger_time_s: float = field(default=10.0, metadata=bounded(0.0, open_lo=True))
    # After a weak answer (no crop the matcher could place), the time trigger asks again after this many seconds
    # instead of trigger_time_s, until a fix is accepted or an answer is rejected otherwise (0: off). A featureless
    # stretch (a straight road between lawns) is crossed with more chances of a crossing or a marking the matcher
    # can place; misses are not fixes, so they do not count in fixes/km. Rejected confident answers are not
    # retried sooner: asked again from nearly the same place, a chance peak repeats and looks like evidence.
    trigger_retry_s: float = field(default=0.0, metadata=bounded(0.0))
    # Distance trigger: also a fix once this many metres were driven since the last accepted one, so the
    # fixes are spread along the road rather than bunched where the covariance grows (0: off); a failed query is
    # retried after trigger_retry_m (a miss is not counted in fixes/km, so it is not budget).
    trigger_distance_m: float = field(default=0.0, metadata=bounded(0.0))
    trigger_retry_m: float = field(default=10.0, metadata=bounded(0.0))
    # Map trigger: with the map's offset modelled (map.georef_sigma_m > 0), a fix is asked while the position is
    # known better than map_trigger_ratio times the offset's 1-sigma in its least known direction (the start, a
    # precise GNSS): such a fix teaches the offset. The first at once, then one every map_trigger_m metres.
    map_trigger_ratio: float = field(default=0.5, metadata=bounded(0.0))
    map_trigger_m: float = field(default=3.0, metadata=bounded(0.0))
    # Deferred weak answers: while the filter is healthy (locked, the safety guard quiet, its prior
    # 1-sigma below trigger_sigma_m), a consensus answer weaker than defer_w is not consumed; the query is asked
    # again defer_retry_m further on, at most defer_max times in a row (then the answer is taken as it is). The
    # filter's prior keeps a process-noise margin (3-5x the true error on KITTI), so it takes a weak answer
    # (FG2 cross-area: ~2.4 m off at w 0.2-0.4, 0.4 m above 0.8) almost at face value, position and speed; the
    # next frames a few metres on give fresh answers. A deferral is neither a fix (fixes/km) nor a failure (loss
    # of lock). 0: off (the kitti profile: 0.6).
    defer_w: float = field(default=0.0, metadata=bounded(0.0, 1.0))
    defer_max: int = field(default=2, metadata=bounded(0))
    defer_retry_m: float = field(default=2.0, metadata=bounded(0.0))
    # ... and only while fewer than trigger_distance_m + defer_span_m were driven since the last accepted fix: a
    # late answer makes each deferral cost its latency in dead reckoning (0: no limit)
    defer_span_m: float = field(default=20.0, metadata=bounded(0.0))
    cross_k: float = field(default=2.0, metadata=bounded(0.0))  # cross arm = clip(k sigma_h, min, max)
    cross_min_m: float = field(default=1.0, metadata=bounded(0.0))
    cross_max_m: float = field(default=10.0, metadata=bounded(0.0))
    # Innovation gate (beside the yaw gate) and consensus over the crops.
    chi2_gate: float = field(default=13.82, metadata=bounded(0.0, open_lo=True))  # 2 dof, 99.9 %
    # the gate for an answer that no other crop of the trigger agrees with (consensus support 1), 2 dof, 95 %
    chi2_gate_single: float = field(default=5.99, metadata=bounded(0.0, open_lo=True))
    consensus_radius_m: float = field(default=3.0, metadata=bounded(0.0))
    # The cluster mean weights each agreeing answer by w^this: 1 weights by w; 2 is inverse-variance weighting under
    # the filter's own w -> sigma mapping (sigma ~ 1/w, Sec. III-F), the consistent choice.
    consensus_weight_power: float = field(default=1.0, metadata=bounded(0.0))
    w_min: float = field(default=0.2, metadata=bounded(0.0, 1.0))  # weaker answers count as misses
    # Adaptive fix noise: the paper's w -> sigma mapping (Sec. III-F) times a scale learnt from the innovations of
    # accepted fixes (covariance matching), clipped to [fix_scale_min, fix_scale_max]; the chi-square gate keeps
    # the unscaled mapping. fix_scale_window: fixes in the exponential average.
    adaptive_fix_noise: bool = True
    fix_scale_min: float = field(default=0.3, metadata=bounded(0.0, open_lo=True))
    fix_scale_max: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))
    fix_scale_window: int = field(default=10, metadata=bounded(1))
    # The scale before any fix has taught one (1: the mapping as it is). A matcher whose calibration is known
    # (the classical matcher on 3-D worlds settles at 0.34-0.40) starts there, so the first fixes, the ones
    # near the start that teach the map's offset, are not discarded as 3x too noisy.
    fix_scale_initial: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    # Both fix sigmas the mean of the paper's forward and lateral ones (Sec. III-F maps w to a 1:2 ellipse, FG2's
    # error shape); for a matcher whose errors are round (the classical one on 3-D streets, docs/matchers.md).
    # taco+ only: paper mode keeps the paper's (its own ablation is ukf.anisotropic).
    fix_isotropic: bool = False
    # Reported accuracy: the filter's position covariance times the a-posteriori variance factor of the
    # accepted fixes (mean NIS / 2 over report_window fixes, clipped to [report_factor_min, report_factor_max]).
    # The filter keeps its process-noise margin (it tracks better with it); what it reports is made honest (while
    # locked and while the safety guard agrees; otherwise the filter's own covariance is reported).
    report_calibration: bool = True
    report_window: int = field(default=20, metadata=bounded(1))
    report_factor_min: float = field(default=0.1, metadata=bounded(0.0, open_lo=True))
    report_factor_max: float = field(default=4.0, metadata=bounded(0.0, open_lo=True))
    # The camera speed's scale error (camera_speed_scale_sigma) as a consider term (core/plus/speed_scale.py):
    # sigma^2 D D^T, D the displacement driven on the camera's speed since the position was last pinned, added to
    # the reported accuracy, and to the position covariance at an accepted fix's capture before its update. The
    # filter fuses the scale error as white noise, but it is one error for all measurements: PX4 SIH's hand-overs
    # ran 0.8-1.0 m ahead after 30 m with 0.5 m reported (docs/px4.md). Off by default (the paper's figures and
    # KITTI have no camera speed); on in the PX4 profiles, where it was measured and flown.
    speed_scale_consider: bool = False
    # Loss of lock and recovery.
    capture_radius_m: float = field(default=20.0, metadata=bounded(0.0, open_lo=True))  # FG2's, Sec. III-D
    lost_after: int = field(default=4, metadata=bounded(1))  # consecutive triggers without an accepted fix
    # ... over at least this long since the last one
    lost_after_s: float = field(default=8.0, metadata=bounded(0.0))
    lost_sigma_min_m: float = field(default=10.0, metadata=bounded(0.0))
    grid_spacing_m: float = field(default=15.0, metadata=bounded(0.0, open_lo=True))
    grid_max_rings: int = field(default=4, metadata=bounded(1, 10))
    recover_interval_s: float = field(default=0.5, metadata=bounded(0.0))  # also the least spacing of triggers
    recover_w_min: float = field(default=0.5, metadata=bounded(0.0, 1.0))
    confirm_fixes: int = field(default=3, metadata=bounded(0))
    # Held jumps (3-D world): the innovation gate is on P + R, and R of a weak match (low w) is large,
    # so a wrong match 15-30 m off with w 0.3-0.6 passed it while the IMU track was good to 1 m, and the true
    # fixes after it were then gated out. An answer that passed the chi-square gate (which still comes first: a
    # confident run of liars is refused until lock is lost) but moves the estimate further than
    # jump_confirm_k sqrt(lambda_max(P) + jump_confirm_floor_m^2) (the prior alone, i.e. the IMU track's own
    # uncertainty, with the fix's error floor beside it) is held ("unconfirmed", a failed trigger) and a verify
    # query is asked at once; 0 disables. 3-D worlds seed 3 / 4, taco+: ATE 127 / 45 m -> 1.8 / 1.4 m with the
    # recovery hold below; KITTI and the flat world unchanged (docs/taco_plus.md, "Held jumps").
    jump_confirm_k: float = field(default=2.0, metadata=bounded(0.0))
    jump_confirm_floor_m: float = field(default=2.0, metadata=bounded(0.0))
    # The same for a recovery answer while lock is lost: the best of a 37-61 crop grid is often a chance peak
    # (w 0.5-0.85 on the 3-D world); distinct grids agreeing by chance are rare. It relocalises (its jump entering
    # P, half of it kept until confirm_fixes later fixes agree) once confirm_answers held answers imply the same
    # correction z - x to within confirm_agree_m + confirm_agree_per_m x the distance driven between them (the
    # IMU's own drift), each within confirm_window_s of the last.
    recover_confirm: bool = True
    confirm_agree_m: float = field(default=3.0, metadata=bounded(0.0))
    confirm_agree_per_m: float = field(default=0.05, metadata=bounded(0.0))
    confirm_window_s: float = field(default=10.0, metadata=bounded(0.0))
    # Agreeing answers needed (the held one included): answers 0.5 s apart see nearly the same view, and a
    # wrong match on a self-similar stretch of road repeats (3-D world: two and three in a row 18-21 m off).
    confirm_answers: int = field(default=3, metadata=bounded(2))
    # Held answers kept at once (the newest): a chance peak between two true answers must not reset the count
    # (3-D world seed 4: true, true, chance, chance, true, true ...).
    confirm_keep: int = field(default=4, metadata=bounded(1))
    # Held answers also agree when one correction plus one speed error carried along the driven track explains
    # them all within confirm_agree_m (at least 3 answers, the speed error at most this, m/s; 0: off). Lock is
    # mostly lost through a bad fix that left the speed (and the accelerometer bias) wrong, and then the error,
    # and so each true answer's correction, grows by metres per second: pairwise agreement within a few metres
    # never comes (docs/taco_plus.md, "Answers that go together by place": cross-area answers).
    confirm_speed_error_mps: float = field(default=3.0, metadata=bounded(0.0))
    # confirm_answers for a held jump while not lost; 0: never (loss of lock and the recovery grid decide). 0 as
    # answers 0.5 s apart share their view: 3-D seed 3 had three in a row 18-21 m off that 3 relocalised onto
    # (ATE 2.5 m; 0: 1.8 m; seed 4 1.37 m either way).
    jump_confirm_answers: int = field(default=0, metadata=bounded(0))
    # A recovery answer is refused beyond this NIS under the widened P (lost_sigma_min_m, half a grid spacing per
    # failed attempt): the grid spans 3 sigma, a candidate far outside it is likelier a chance peak (0: off).
    recover_chi2_gate: float = field(default=0.0, metadata=bounded(0.0))
