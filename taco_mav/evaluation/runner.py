"""Run the Localiser over one drive, deterministically, with a matcher and an optional matcher latency.

The loop is the daemon's, minus sockets: IMU samples in data-time order; when the trigger fires the matcher
answers the query for the frame nearest the capture time, and the answer is handed back `latency_s` of data
time later through the Localiser's delayed-fix path (or applied on arrival, per the profile).

A drive's frames need not fall on the Localiser's frame times: a recording (`taco-mav run --record`) keeps frames
at 5 Hz on the autopilot clock, up to 0.1 s (more where the recorder skipped a slot) from the 10 Hz capture times
of the queries, where the live daemon's camera had a frame within one IMU period. The matcher places the vehicle
where it was when its frame was taken, and the Localiser applies the answer at the capture time; so the query is
asked as at the frame's time (`QueryFrames`): its crops moved by the vehicle's motion between the two times,
which carries the answer back to the capture time. That motion is the camera's own (the ground motion between
the frame and the drive's frame on the other side of the capture time, `cvgl.ground_motion`, taken as steady
between them), else the Localiser's speed along its heading. A frame further than MAX_FRAME_GAP_S from the
capture time (the recording stopped or skipped more) is none: the query is cancelled and asked again.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import Counter
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
from taco_mav.cvgl.ground_motion import MIN_GAP_S, GroundMotion
from taco_mav.cvgl.registry import make_matcher
from taco_mav.cvgl.satellite import SatelliteMap
from taco_mav.cvgl.service import profile_service
from taco_mav.datasets.base import Drive
from taco_mav.errors import DataError, MatcherError
from taco_mav.evaluation.camera_motion import OfflineMotion
from taco_mav.evaluation.wheel_replay import WheelReplay
from taco_mav.progress import progress_bar

log = logging.getLogger(__name__)

NEEDS_IMAGES = ("classical", "fg2")
# Largest |frame time - capture time| of a frame a query is answered with, s: beyond it the turn between the two
# times is no longer negligible in the query's move (a 5 Hz recording's frames are at most 0.1 s off, 0.2 s where
# the recorder skipped a slot).
MAX_FRAME_GAP_S = 0.5
SAME_TIME_S = 1e-6  # a frame this close to the capture time is taken at it (the Localiser's own tolerance)


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


class QueryFrames:
    """Which of a drive's frames answers a query, and the query as asked for it (module docstring). drive: its
    frame_times (s, the IMU's clock), frame(i) images and IMU (the compass's turn between two times); camera: the
    drive's ground camera; ego_rows: image rows showing the vehicle (profile `classical.ego_mask_rows`).
    `counts`: how each query was answered ("at_capture", "camera_motion", "speed", "no_frame")."""

    def __init__(self, drive: Drive, camera: GroundCamera, ego_rows: int = 0) -> None:
        self.drive, self.camera = drive, camera
        self.times = np.asarray(drive.frame_times, dtype=float)
        try:
            self.motion: GroundMotion | None = GroundMotion(camera, ego_rows=ego_rows)
        except ValueError as e:  # the camera sees too little ground ahead: the Localiser's speed moves the query
            log.debug("drive %s: frames aligned by speed only (%s)", drive.name, e)
            self.motion = None
        self._imu_t = np.asarray(drive.imu.t, dtype=float)
        self._yaw = np.unwrap(np.asarray(drive.imu.rpy_ned[:, 2], dtype=float))  # NED rad, CW
        self.counts: Counter[str] = Counter()

    def ask(self, q: FixQuery, speed: float) -> tuple[FixQuery, GroundFrame] | None:
        """(the query as asked at its frame's time, the frame nearest its capture time, stamped with its own time),
        or None when no frame is within MAX_FRAME_GAP_S. speed: the Localiser's forward speed at the capture time,
        m/s (used where the camera cannot measure the motion)."""
        i = int(np.argmin(np.abs(self.times - q.capture_t)))
        t_f = float(self.times[i])
        if not abs(t_f - q.capture_t) <= MAX_FRAME_GAP_S:
            self.counts["no_frame"] += 1
            return None
        frame = GroundFrame(self.drive.frame(i), t_f, self.camera)
        if abs(t_f - q.capture_t) < SAME_TIME_S:
            self.counts["at_capture"] += 1
            return q, frame
        moved = self._camera_move(q, i, frame.image)
        if moved is None:
            self.counts["speed"] += 1
            moved = float(speed) * (t_f - q.capture_t) * np.array([math.cos(q.heading), math.sin(q.heading)])
            if not np.all(np.isfinite(moved)):
                moved = np.zeros(2)
        else:
            self.counts["camera_motion"] += 1
        return moved_query(q, moved), frame

    def _theta(self, t: float, q: FixQuery) -> float:
        """Compass heading at time t, ENU rad: the query's, turned as the IMU's yaw turned since its capture."""
        yaw = np.interp([t, q.capture_t], self._imu_t, self._yaw)
        return float(q.heading - (yaw[0] - yaw[1]))

    def _camera_move(self, q: FixQuery, i: int, image: np.ndarray) -> np.ndarray | None:
        """The vehicle's motion from the capture time to frame i's time, ENU metres, from the camera: the ground
        motion between frame i and the frame on the other side of the capture time, at a steady velocity between
        the two; None where there is no such frame or the camera measures nothing."""
        t_f = float(self.times[i])
        j = i + 1 if t_f < q.capture_t else i - 1
        if self.motion is None or not 0 <= j < len(self.times):
            return None
        a, b = (i, j) if i < j else (j, i)
        t_a, t_b = float(self.times[a]), float(self.times[b])
        if not MIN_GAP_S * 0.5 <= t_b - t_a <= 2.0 * MAX_FRAME_GAP_S:
            return None
        other = self.drive.frame(j)
        th_a, th_b = self._theta(t_a, q), self._theta(t_b, q)
        try:
            m = self.motion.measure(image if a == i else other, other if a == i else image, th_b - th_a)
        except DataError:  # frames of another size than the camera model
            return None
        if m is None:
            return None
        c, s = math.cos(th_a), math.sin(th_a)
        ab = np.array([c * m.d_fwd - s * m.d_left, s * m.d_fwd + c * m.d_left])  # frame a to frame b, ENU m
        return ab * (t_f - q.capture_t) / (t_b - t_a)


def moved_query(q: FixQuery, d: np.ndarray) -> FixQuery:
    """The query with its search centre and crop centres moved by d (ENU metres, shape (2,)); heading and capture
    time kept. Asked for a frame taken where the vehicle was d from its capture position, the matcher's answer
    relative to the moved crops is the answer relative to the query's own crops at the capture position."""
    d = np.asarray(d, dtype=float)
    if not np.any(d):
        return q
    return dataclasses.replace(q, centre=np.asarray(q.centre, dtype=float) + d,
                               crop_centres=np.asarray(q.crop_centres, dtype=float) + d)


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

    frames = None
    if profile.matcher in NEEDS_IMAGES:
        if len(drive.frame_times) == 0:
            raise MatcherError(f"drive {drive.name}: matcher '{profile.matcher}' needs camera images and this drive "
                               "has none (use --matcher emulator on image-less KITTI OXTS drives)")
        frames = QueryFrames(drive, camera, profile.classical.ego_mask_rows)
    empty = np.zeros((0, 0, 3), np.uint8)
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
    # taco+'s wheel encoders, as the daemon feeds them (daemon/wheels.py), on a recording that has them
    wheels = WheelReplay(drive.wheels, profile.wheels) \
        if profile.wheels.enabled and drive.wheels is not None and loc.aids is not None else None
    for i, sample in enumerate(progress_bar(imu.samples(), total=len(imu), desc=drive.name, enabled=progress)):
        loc.add_imu(sample)
        if wheels is not None:
            wheels.tick(loc, sample.t)
        if len(loc.record.track) > len(reported):  # a frame closed: what the daemon would report now
            reported.append(_cov3(loc.estimate().cov_xy))
        dead.add(sample)
        dead_xy[i] = (dead.x, dead.y)
        if motion is not None:
            motion.tick(loc)
        q = loc.poll_query()
        if q is not None:
            got = (q, GroundFrame(empty, q.capture_t, camera)) if frames is None else \
                frames.ask(q, loc.estimate().speed)
            if got is None:  # no frame near its capture time (a recording that stopped): asked again later
                loc.cancel_query(q.query_id)
            else:
                pending.append((q.capture_t + latency_s, q.query_id, service.answer(*got)))
        while pending and pending[0][0] <= sample.t + 1e-9:
            _, qid, results = pending.pop(0)
            loc.add_fix(qid, results)

    track = np.array(loc.record.track)
    t = track[:, 0]
    gt = np.array([truth.pose_at(ti) for ti in t])
    smoothed = loc.smoothed() if profile.smoother.enabled else None
    imu_only = np.column_stack([np.interp(t, imu.t, dead_xy[:, 0]), np.interp(t, imu.t, dead_xy[:, 1])])
    centre_err = [float(np.hypot(*(q.centre - np.array(truth.pose_at(q.capture_t)[:2])))) for q in loc.record.queries]
    n_frames = len(drive.frame_times) if len(drive.frame_times) else len(t)
    return DriveRun(
        name=drive.name, sequence=drive.sequence, t=t, truth_xy=gt[:, :2], truth_theta=gt[:, 2],
        online_xy=track[:, 1:3], online_theta=track[:, 3], online_var=track[:, 4:7], imu_only_xy=imu_only,
        smoothed=smoothed, queries=list(loc.record.queries), outcomes=list(loc.record.outcomes), frames_available=n_frames,
        matcher_s=service.stats.matcher_s, wall_s=time.perf_counter() - wall0, origin_utm=origin,
        utm_epsg=int(drive.utm_epsg), mosaic=str(drive.mosaic) if drive.mosaic else None,
        reported_var=np.array(reported) if len(reported) == len(t) else None,
        extra={"crops_off_map": service.stats.crops_off_map, "search_centre_errors": centre_err, "heading0": th0,
               "convergence_rad": convergence if math.isfinite(convergence) else 0.0,
               "lock_events": loc.record.lock_events,
               "query_frames": dict(frames.counts) if frames is not None else {},
               "camera_motion": dict(motion.counts) if motion is not None else {},
               **({"wheels": dict(wheels.counts)} if wheels is not None else {})},
    )
