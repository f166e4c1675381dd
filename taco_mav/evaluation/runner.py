"""Run the Localiser over one drive, deterministically, with a matcher and an optional matcher latency.

The loop is the daemon's, minus sockets: IMU samples in data-time order; when the trigger fires the matcher
answers the query for the frame nearest the capture time, and the answer is handed back `latency_s` of data
time later through the Localiser's delayed-fix path (or applied on arrival, per the profile).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import Profile, localiser_params
from taco_mav.core.frames import FixOutcome
from taco_mav.core.localiser import make_localiser
from taco_mav.core.preintegration import Preintegrator
from taco_mav.core.smoother import SmoothResult
from taco_mav.core.types import FixQuery
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.registry import make_matcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.cvgl.service import profile_service
from taco_mav.datasets.base import Drive
from taco_mav.errors import MatcherError
from taco_mav.evaluation.camera_motion import OfflineMotion
from taco_mav.progress import progress_bar

log = logging.getLogger(__name__)

NEEDS_IMAGES = ("classical", "fg2")


@dataclass
class DriveRun:
    """Everything one run produced. Arrays are at the Localiser's frame times t (N,): truth_xy, online_xy
    (ENU metres rel. origin), truth_theta, online_theta (ENU grid rad), imu_only_xy; smoothed (N, 3) or None."""

    name: str
    sequence: str | None
    t: np.ndarray
    truth_xy: np.ndarray
    truth_theta: np.ndarray
    online_xy: np.ndarray
    online_theta: np.ndarray
    online_var: np.ndarray
    imu_only_xy: np.ndarray
    smoothed: SmoothResult | None
    queries: list[FixQuery]
    outcomes: list[FixOutcome]
    frames_available: int
    matcher_s: float
    wall_s: float
    origin_utm: np.ndarray
    utm_epsg: int
    mosaic: str | None = None
    extra: dict = field(default_factory=dict)
    # The position covariance the Localiser reported (Estimate.cov_xy: what the daemon sends as h_acc) at each
    # frame, columns Pxx, Pxy, Pyy in m^2 (N, 3); None where not recorded (then online_var stands in).
    reported_var: np.ndarray | None = None


def _cov3(cov: np.ndarray) -> tuple[float, float, float]:
    """(Pxx, Pxy, Pyy) of a 2x2 covariance, m^2."""
    return float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])


def _frame_source(drive: Drive, matcher: str, camera: GroundCamera):
    """A function capture_t -> GroundFrame for this drive and matcher (images only when the matcher needs them)."""
    if matcher not in NEEDS_IMAGES:
        empty = np.zeros((0, 0, 3), np.uint8)
        return lambda t: GroundFrame(empty, t, camera)
    times = np.asarray(drive.frame_times, dtype=float)
    if times.size == 0:
        raise MatcherError(f"drive {drive.name}: matcher '{matcher}' needs camera images and this drive has none "
                           "(use --matcher emulator on image-less KITTI OXTS drives)")

    def frame_at(t: float) -> GroundFrame:
        i = int(np.argmin(np.abs(times - t)))
        return GroundFrame(drive.frame(i), t, camera)

    return frame_at


def run_drive(drive: Drive, profile: Profile, *, latency_s: float = 0.0, progress: bool = False,
              cross_area: bool = False, sat_map: SatelliteMap | None = None) -> DriveRun:
    """Evaluate one drive with `profile` (its matcher, estimator switches and latency handling)."""
    wall0 = time.perf_counter()
    params = localiser_params(profile)
    truth = drive.truth
    origin = np.asarray(drive.origin_utm, dtype=float)
    convergence = float(getattr(drive, "convergence_rad", 0.0))
    camera = drive.camera or GroundCamera.from_config(profile.camera)

    def truth_utm(t: float) -> tuple[float, float, float]:
        x, y, th = truth.pose_at(t)
        return origin[0] + x, origin[1] + y, th

    frame_at = _frame_source(drive, profile.matcher, camera)
    matcher = make_matcher(profile, truth_utm, cross_area=cross_area, camera=camera)
    if profile.matcher in NEEDS_IMAGES and sat_map is None:
        if drive.mosaic is None:
            raise MatcherError(f"drive {drive.name}: matcher '{profile.matcher}' needs a satellite mosaic and the "
                               "drive has none (a synthetic world's world.json names one)")
        sat_map = SatelliteMap(drive.mosaic)
    service = profile_service(matcher, sat_map, origin, profile)

    imu = drive.imu
    t0 = float(imu.t[0])
    x0, y0, th0 = truth.pose_at(t0)
    loc = make_localiser(params, t0, x0, y0, th0, drive.start.speed, record=True, heading_offset=convergence)
    dead = Preintegrator.from_params(params.imu, t0, x0, y0, th0, drive.start.speed, convergence)
    dead_xy = np.zeros((len(imu), 2))
    reported = [_cov3(loc.estimate().cov_xy)]
    pending: list[tuple[float, int, list]] = []
    # taco+'s camera speed, as the daemon feeds it (daemon/motion.py), on a drive with camera frames
    motion = None
    if profile.matcher in NEEDS_IMAGES and loc.takes_ground_motion and profile.plus.camera_speed \
            and len(drive.frame_times) >= 2:
        try:
            motion = OfflineMotion(drive, camera, profile.classical.ego_mask_rows)
        except ValueError as e:  # the camera sees too little ground ahead: as the daemon, speed is the IMU's
            log.warning("drive %s: camera speed off (plus.camera_speed): %s", drive.name, e)
    for i, sample in enumerate(progress_bar(imu.samples(), total=len(imu), desc=drive.name, enabled=progress)):
        loc.add_imu(sample)
        if len(loc.track) > len(reported):  # a frame closed: what the daemon would report now
            reported.append(_cov3(loc.estimate().cov_xy))
        dead.add(sample)
        dead_xy[i] = (dead.x, dead.y)
        if motion is not None:
            motion.tick(loc)
        q = loc.poll_query()
        if q is not None:
            pending.append((q.capture_t + latency_s, q.query_id, service.answer(q, frame_at(q.capture_t))))
        while pending and pending[0][0] <= sample.t + 1e-9:
            _, qid, results = pending.pop(0)
            loc.add_fix(qid, results)

    track = np.array(loc.track)
    t = track[:, 0]
    gt = np.array([truth.pose_at(ti) for ti in t])
    smoothed = loc.smoothed() if profile.smoother.enabled else None
    imu_only = np.column_stack([np.interp(t, imu.t, dead_xy[:, 0]), np.interp(t, imu.t, dead_xy[:, 1])])
    centre_err = [float(np.hypot(*(q.centre - np.array(truth.pose_at(q.capture_t)[:2])))) for q in loc.queries]
    n_frames = len(drive.frame_times) if len(drive.frame_times) else len(t)
    return DriveRun(
        name=drive.name, sequence=drive.sequence, t=t, truth_xy=gt[:, :2], truth_theta=gt[:, 2],
        online_xy=track[:, 1:3], online_theta=track[:, 3], online_var=track[:, 4:7], imu_only_xy=imu_only,
        smoothed=smoothed, queries=list(loc.queries), outcomes=list(loc.outcomes), frames_available=n_frames,
        matcher_s=service.stats.matcher_s, wall_s=time.perf_counter() - wall0, origin_utm=origin,
        utm_epsg=int(drive.utm_epsg), mosaic=str(drive.mosaic) if drive.mosaic else None,
        reported_var=np.array(reported) if len(reported) == len(t) else None,
        extra={"crops_off_map": service.stats.crops_off_map, "search_centre_errors": centre_err, "heading0": th0,
               "convergence_rad": convergence if math.isfinite(convergence) else 0.0,
               "lock_events": loc.lock_events,
               "camera_motion": dict(motion.counts) if motion is not None else {}},
    )
