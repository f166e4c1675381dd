"""Value types shared by the estimator, the matchers, the datasets and the link.

Frames and units (see DESIGN.md):
- world: UTM easting/northing metres (ENU) relative to the start-up fix; heading theta 0 = east, CCW positive.
- body (IMU): FRD; specific force in m/s^2 (gravity included, as RAW_IMU reports it), gyro in rad/s.
- attitude: roll, pitch, yaw in radians, NED (yaw 0 = north, CW positive).
- planar body frame for increments and crop offsets: (forward, left) metres, dtheta CCW radians.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from taco_mav.core import kernels as _k


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU sample as an autopilot reports it.

    t: seconds on the autopilot clock. accel_frd: body FRD specific force, m/s^2 (level at rest: z = -9.81).
    gyro_frd: body FRD angular rate, rad/s. roll, pitch, yaw: attitude in radians, NED (yaw 0 = north, CW).
    """

    t: float
    accel_frd: tuple[float, float, float]
    gyro_frd: tuple[float, float, float]
    roll: float
    pitch: float
    yaw: float


@dataclass(frozen=True, slots=True)
class MatchResult:
    """One matcher answer for one crop (paper Sec. III-C: the tuple (R, t, w)).

    R: 2x2 residual rotation between the matcher's heading and the query heading (psi_res = atan2(R10, R00),
    CCW positive). t: the vehicle position relative to the crop centre, metres, in the crop's heading-up frame
    expressed as (forward, left): forward = image up, left = image left. w: match weight in (0, 1].
    elapsed_s: wall time the matcher spent on this crop (the batch time divided among crops). null_w: the
    trigger's chance level, the highest w the matcher gave the trigger's decoy crops (a heading known wrong)
    while taking that heading as right; None when the trigger had no decoys (core/answer_check.py).
    """

    R: np.ndarray
    t: np.ndarray
    w: float
    elapsed_s: float = 0.0
    null_w: float | None = None



@dataclass(frozen=True, slots=True)
class FixQuery:
    """What the Localiser asks the matcher for when its trigger fires (paper Sec. III-D).

    capture_t: autopilot time of the frame to match, seconds. centre: forward-biased search centre, ENU metres
    (shape (2,)). heading: compass heading theta at capture, ENU radians (0 = east, CCW). offsets_body: the
    body-frame offsets (forward, left) metres around the centre, shape (K, 2) (K = 5 in paper mode: back,
    centre, forward, left, right; K = 1 for the single-crop ablation). crop_centres: the same in the world,
    ENU metres relative to the origin, shape (K, 2) (add the origin's UTM easting/northing for map crops);
    crop k is requested at crop_centres[k] with the query heading and its MatchResult goes back in the same
    order. epsilon: the IMU error envelope that sized the search, metres. query_id: increasing id.
    """

    query_id: int
    capture_t: float
    centre: np.ndarray
    heading: float
    offsets_body: np.ndarray
    crop_centres: np.ndarray
    epsilon: float
    reason: str = "error"  # which branch of the dual trigger fired: "error" or "time"


@dataclass(frozen=True, slots=True)
class Estimate:
    """The Localiser's current state.

    t: autopilot time, seconds. xy: ENU metres relative to the origin, shape (2,). theta: heading, ENU radians.
    speed: forward speed, m/s. cov_xy: 2x2 position covariance, m^2. epsilon: IMU error envelope, metres.
    since_fix_s: seconds since the last accepted fix (or since start). sigma_speed: the filter's own 1-sigma of
    `speed`, m/s (taco+'s speed-error state; NaN where the filter has none, as the paper's). filter_sigma_h: the
    filter's own horizontal 1-sigma, m, before any calibration of the reported accuracy (what a new Localiser
    carrying this one on must start from).
    """

    t: float
    xy: np.ndarray
    theta: float
    speed: float
    cov_xy: np.ndarray
    epsilon: float
    since_fix_s: float = 0.0
    extra: dict = field(default_factory=dict)
    sigma_speed: float = math.nan
    filter_sigma_h: float = math.nan

    @property
    def sigma_h(self) -> float:
        """1-sigma horizontal accuracy, metres: sqrt of the largest eigenvalue of cov_xy."""
        return horizontal_sigma(self.cov_xy)

    def floored(self, sigma_m: float) -> Estimate:
        """This estimate with no horizontal 1-sigma below sigma_m (m): the difference to the smaller eigenvalue of
        cov_xy added to both variances; itself when none is below (or cov_xy is not finite)."""
        lo = float(np.linalg.eigvalsh(self.cov_xy).min()) if np.all(np.isfinite(self.cov_xy)) else math.inf
        if lo >= sigma_m**2:
            return self
        return dataclasses.replace(self, cov_xy=self.cov_xy + (sigma_m**2 - lo) * np.eye(2))


def horizontal_sigma(cov: np.ndarray) -> float:
    """1-sigma horizontal accuracy, metres: sqrt of the largest eigenvalue of the 2x2 position block of cov
    (m^2)."""
    return float(_k.horizontal_sigma(np.asarray(cov, dtype=float)))  # compiled: numpy's eigvalsh, bit for bit


@dataclass(frozen=True, slots=True)
class GnssFix:
    """One real GNSS reading for `Localiser.add_gnss`. t: autopilot seconds; xy: position, ENU metres from
    the origin (UTM grid); vel_en: ground velocity (east, north) m/s, or None when the receiver gave none;
    sigma_h_m: 1-sigma horizontal position accuracy, metres (h_acc, or HDOP x UERE); sigma_v_mps: 1-sigma
    speed accuracy, m/s (v_acc, or a default)."""

    t: float
    xy: np.ndarray
    vel_en: np.ndarray | None
    sigma_h_m: float
    sigma_v_mps: float


@dataclass(frozen=True, slots=True)
class GnssOutcome:
    """What the Localiser did with one GnssFix. used: fused (or taken for re-anchoring in paper mode); reason:
    "fused", "anchored", "rejected" (the spoofing/jamming guard holds it off), "nonfinite", "stale" or
    "ignored"; nis: position normalised innovation squared against the prediction; window_nis: the guard's
    windowed statistic; innovation_m: |position innovation|, metres."""

    used: bool
    reason: str
    nis: float = 0.0
    window_nis: float = 0.0
    innovation_m: float = 0.0
