"""Real GNSS and its spoofing/jamming guard (not in the paper): the one definition of the parameters,
their defaults and where each comes from. A profile's `gnss:` section loads into it; core/gnss/guard.py and
core/gnss/fusion.py read it. Lengths metres, angles radians, times seconds."""

from __future__ import annotations

from dataclasses import dataclass, field

from taco_mav.core.fields import bounded

__all__ = ["GnssParams"]


@dataclass(frozen=True)
class GnssParams:
    """Real GNSS while it is honest, and the spoofing/jamming guard (not in the paper: it takes one
    GNSS reading at start-up). Both estimators take `Localiser.add_gnss`: taco+ fuses position, speed and course
    (calibrating speed error, accelerometer and compass bias), paper mode re-anchors on it. The guard tests each
    reading against the filter's state `reference_lag_s` earlier carried forward by IMU dead reckoning alone
    (core/gnss/guard.py). Defaults were set on synthetic drives with the automotive IMU preset (the pessimistic
    one, docs/taco_plus.md) and the simulator's receiver (white sigma_h / 2, Gauss-Markov bias 0.87 sigma_h,
    tau 60 s): honest 1.5 m readings accepted 100 % of the time, velocity-dragging spoofs caught in 1-2 s."""

    enabled: bool = True  # False: add_gnss ignores every reading
    # Measurements. A receiver's h_acc below 0.5 m is taken as 0.5 (an RTK fix would otherwise pin the filter).
    sigma_h_min_m: float = field(default=0.5, metadata=bounded(0.0, open_lo=True))
    sigma_v_min_mps: float = field(default=0.1, metadata=bounded(0.0, open_lo=True))  # floor on vel_acc
    # Speed and course are fused above this ground speed (course is noise when standing; 1 m/s).
    min_speed_mps: float = field(default=1.0, metadata=bounded(0.0))
    # Course as a heading measurement: 1-sigma = max(this, vel_acc / speed); 0.03 rad covers a ground vehicle's
    # side slip in ordinary turns and the antenna's lever arm.
    course_sigma_min_rad: float = field(default=0.03, metadata=bounded(0.0, open_lo=True))
    max_age_s: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))  # older (or newer) than the IMU: stale
    # A reading moves the estimate this late (rewind and replay, as a late camera fix), so the guard has seen
    # the readings after it: 1 s lets the velocity test (which catches a velocity-dragging spoof in 1-2 s) reject
    # before the first dragged reading is fused, and costs the reported accuracy little (1.4 m 1-sigma on the
    # synthetic drives against 1.3 m undelayed; 2 s: 4 m with the synthetic profile's loose speed model).
    fuse_delay_s: float = field(default=1.0, metadata=bounded(0.0))
    fuse_interval_s: float = field(default=0.5, metadata=bounded(0.0))  # batches: one rewind and replay each
    # The receiver's error model: white noise of white_fraction x its reported sigma, the rest a wandering bias
    # (first-order Gauss-Markov, correlation time bias_tau_s), as real receivers wander (multipath, atmosphere)
    # and as the simulator models them (white sigma / 2, tau 60 s).
    white_fraction: float = field(default=0.5, metadata=bounded(0.0, 1.0, open_lo=True))
    bias_tau_s: float = field(default=60.0, metadata=bounded(0.0, open_lo=True))
    # The shadow references: the filter's state this long before a reading (in the frame history, so at most
    # latency.history_s), carried forward by dead reckoning. 7 s: a 0.5 m/s drag has moved 3.5 m while the
    # automotive IMU's dead reckoning has drifted ~0.6 m and the receiver's bias ~0.6 m (1 sigma each).
    reference_lag_s: float = field(default=7.0, metadata=bounded(0.0, open_lo=True))
    # ... 3 s for the velocity test: a speed error grows with the shadow's age (automotive ~0.05 m/s per s).
    velocity_lag_s: float = field(default=3.0, metadata=bounded(0.0, open_lo=True))
    # Dead-reckoning error growth of a shadow beyond the estimator's own uncertainty at its anchor, from shadows
    # of taco+ on synthetic drives with the automotive preset after GNSS calibration (error at 7 s: along 0.6 m,
    # across 0.45 m RMS): speed 0.05 m/s, acceleration 0.03 m/s^2, heading 0.012 rad (times the distance),
    # position random walk 0.05 m/sqrt(s); an estimator without a bias state (paper mode) also leaves the
    # accelerometer bias, 0.05 m/s^2 (3 mg turn-on bias and 0.2 deg of AHRS tilt, 1 sigma).
    dr_speed_sigma_mps: float = field(default=0.05, metadata=bounded(0.0))
    dr_accel_sigma_mps2: float = field(default=0.03, metadata=bounded(0.0))
    dr_heading_sigma_rad: float = field(default=0.012, metadata=bounded(0.0))
    dr_pos_rw_mps: float = field(default=0.05, metadata=bounded(0.0))
    dr_accel_bias_sigma_mps2: float = field(default=0.05, metadata=bounded(0.0))
    # The shadows' modelled growth (the drift above plus the estimator's own speed, bias and heading
    # uncertainty, which taco+ keeps loose on purpose) is scaled by what accepted readings show (covariance
    # matching over dr_scale_n readings, clipped to [dr_scale_min, dr_scale_max]; 1 until then), and by at least
    # held_scale_min while the receiver is held off (the shadow then ages past the lag the scale was learnt at).
    dr_scale_min: float = field(default=0.1, metadata=bounded(0.0, open_lo=True))
    dr_scale_max: float = field(default=4.0, metadata=bounded(0.0, open_lo=True))
    dr_scale_n: int = field(default=200, metadata=bounded(1))
    held_scale_min: float = field(default=0.3, metadata=bounded(0.0))
    # Tests. Mean NIS over window_s against chi2(2 N, 1 - window_alpha) / N, N one reading per window_corr_s
    # (the readings' errors are correlated); mean innovation of the last drift_window_s (position, and velocity)
    # against chi2(2 dof) drift_gate = 99.9 %; one reading against the filter: hard_gate = 99.99 %.
    window_s: float = field(default=10.0, metadata=bounded(0.0, open_lo=True))
    window_alpha: float = field(default=1e-4, metadata=bounded(0.0, 0.5, open_lo=True))
    window_min_n: int = field(default=5, metadata=bounded(1))
    window_corr_s: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
    drift_window_s: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))
    drift_gate: float = field(default=13.82, metadata=bounded(0.0, open_lo=True))
    hard_gate: float = field(default=18.42, metadata=bounded(0.0, open_lo=True))
    # The first reading after a loss or a rejection is fused only if the update moves the estimate by at most
    # 3 sigma of its covariance ((3 sigma)^2 = 9), so the output never jumps further at a hand-over.
    jump_gate: float = field(default=9.0, metadata=bounded(0.0, open_lo=True))
    gap_s: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))  # no reading this long: receiver lost
    # A rejected receiver is used again after every test has passed, with the drift and velocity statistics
    # below suspect_gate (2 dof, 95 %), for reaccept_s: it must agree again for a sustained period.
    reaccept_s: float = field(default=10.0, metadata=bounded(0.0))
    suspect_gate: float = field(default=5.99, metadata=bounded(0.0, open_lo=True))
    # Camera fixes cross-check the receiver: one every camera_interval_s while it is healthy, one after
    # camera_check_s when the guard is suspicious; camera_disagree_n fixes in a row beyond camera_gate (2 dof,
    # 99.9 %) of their combined covariance (camera, the readings within camera_match_s averaged, the receiver's
    # bias) reject the receiver, and the last one's distance from the readings floors the reported accuracy
    # (GnssGuard.camera_floor_m). At 5 s a 0.2 m/s drag stays within 2 sigma 99-100 % of the time (at 20 s
    # 44-79 %), and honest readings' reports cover their bias of 1.8 m RMS (2.0 m reported, 100 % within 2 sigma;
    # at 20 s 1.3 m): tests/test_localiser_gnss.py's drag too slow for the shadow tests. Costs no more than the
    # trigger without GNSS, which asks about every 4.6 s in the companion bench (0.095 core, docs/companion.md).
    camera_interval_s: float = field(default=5.0, metadata=bounded(0.0))
    camera_check_s: float = field(default=3.0, metadata=bounded(0.0))
    camera_gate: float = field(default=13.82, metadata=bounded(0.0, open_lo=True))
    camera_disagree_n: int = field(default=2, metadata=bounded(1))
    camera_match_s: float = field(default=1.0, metadata=bounded(0.0, open_lo=True))
