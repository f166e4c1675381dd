"""Builders for the fault tests: the daemon's fix pipeline (`FixPipeline`: camera, frame guard, satellite map,
matcher worker thread) driven by a real Localiser over a simulated drive, a matcher that answers from the
truth (or misbehaves on cue), camera folders of real PNG files and a real UTM GeoTIFF.

Frames and units: the drive is ENU metres from the origin (tests/helpers.simulate); the origin is at
(ORIGIN_LAT, ORIGIN_LON); camera folders are on the autopilot clock (frame i at i / rate_hz s).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np
import rasterio
from helpers import SimDrive, simulate

from taco_mav.config import Profile, localiser_params, profile_from_dict
from taco_mav.core.localiser import Localiser
from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.daemon.daemon import DaemonOptions
from taco_mav.daemon.eventlog import EventLog
from taco_mav.daemon.fixes import FixPipeline
from taco_mav.mavlink.encoders import Origin
from taco_mav.mavlink.timesync import ClockMap

ORIGIN_LAT, ORIGIN_LON = 49.0, 8.4
CAMERA = {"width_px": 160, "height_px": 120, "cx": 80.0, "cy": 60.0, "fx": 100.0, "fy": 100.0}


def small_camera_profile(**extra: object) -> Profile:
    """The default profile with a 160 x 120 camera and the emulator matcher setting (no camera needed)."""
    return profile_from_dict({"matcher": "emulator", "camera": CAMERA, **extra})


class TruthMatcher:
    """Answers every crop with the drive's true position at the frame time (R = I, w = 0.9); `fault(call)`
    may raise, sleep or return something else for the call-th call (0-based) instead."""

    name = "truth"
    needs_true_pose = True  # it answers from the drive's truth (not the daemon's) and needs no camera

    def __init__(self, drive: SimDrive, origin: Origin,
                 fault: Callable[[int], object] | None = None) -> None:
        self.drive, self.origin, self.fault = drive, origin, fault
        self.calls = 0

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        call, self.calls = self.calls, self.calls + 1
        if self.fault is not None:
            planted = self.fault(call)
            if planted is not None:
                return planted  # type: ignore[return-value]
        x, y, _ = self.drive.pose_at(frame.t)
        out = []
        for crop in crops:
            d = self.origin.utm + np.array([x, y]) - crop.centre_utm
            c, s = math.cos(crop.heading), math.sin(crop.heading)
            out.append(MatchResult(np.eye(2), np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]]), 0.9))
        return out


@dataclass
class Counters:
    """What the daemon keeps for the pipeline (FixCounters)."""

    queries: int = 0
    fixes: Counter[str] = field(default_factory=Counter)


@dataclass
class PipelineRun:
    """The outcome: the pipeline, its Localiser, counters, STATUSTEXTs, and sigma_h (m) per 0.5 s."""

    pipe: FixPipeline
    loc: Localiser
    stats: Counters
    texts: list[str]
    t: np.ndarray
    sigma: np.ndarray
    errors: np.ndarray  # |estimate - truth| m at the same times
    matcher: TruthMatcher
    stop_s: float  # wall seconds FixPipeline.stop took


def straight_drive(duration_s: float, speed: float = 5.0, theta0: float = 0.3) -> SimDrive:
    """A straight drive at `speed` m/s, heading theta0 (ENU rad), 50 Hz IMU, no noise."""
    return simulate(lambda t: speed, lambda t: 0.0, duration_s, rate_hz=50.0, theta0=theta0)


def run_pipeline(profile: Profile, drive: SimDrive, matcher_fault: Callable[[int], object] | None = None, *,
                 camera: str | None = None, map_path: Path | None = None, wait_s: float = 3.0,
                 matcher_timeout_s: float = 10.0, step_sleep_s: float = 0.0) -> PipelineRun:
    """Play `drive` into a Localiser; the pipeline answers its queries in its worker thread. After each
    submitted query the loop waits up to wait_s (wall) for the answer, so the run is deterministic; matcher_fault:
    see TruthMatcher; camera: a --camera spec; map_path: a GeoTIFF (crops off it are None)."""
    origin = Origin.from_latlon(ORIGIN_LAT, ORIGIN_LON, 100.0)
    matcher = TruthMatcher(drive, origin, matcher_fault)
    opts = DaemonOptions(connect="udpin:127.0.0.1:1", camera=camera, map_path=map_path,
                         matcher_timeout_s=matcher_timeout_s)
    stats, texts = Counters(), []
    pipe = FixPipeline(profile=profile, options=opts, clockmap=ClockMap(), stats=stats,
                       status=lambda sev, text, key: texts.append(text), matcher=matcher)
    pipe.open(EventLog(None))
    pipe.start()
    pipe.on_origin(origin)
    s0 = drive.samples[0]
    loc = Localiser(localiser_params(profile), s0.t, heading=float(drive.theta[0]), speed=float(drive.speed[0]),
                    record=False)
    ts, sig, err = [], [], []
    try:
        for k, s in enumerate(drive.samples):
            loc.add_imu(s)
            pipe.drain(loc, 1)
            asked = stats.queries
            pipe.poll(loc, 1)
            if stats.queries > asked and loc.desk.in_flight and wait_s > 0:  # submitted, not cancelled
                deadline = time.monotonic() + wait_s
                while pipe._results.empty() and time.monotonic() < deadline:
                    time.sleep(0.001)
                pipe.drain(loc, 1)
            if step_sleep_s:
                time.sleep(step_sleep_s)
            if k % 25 == 0:
                est = loc.estimate()
                x, y, _ = drive.pose_at(s.t)
                ts.append(s.t)
                sig.append(est.sigma_h)
                err.append(math.hypot(est.xy[0] - x, est.xy[1] - y))
    finally:
        t0 = time.monotonic()
        pipe.stop()
        stop_s = time.monotonic() - t0
        pipe.close()
    return PipelineRun(pipe, loc, stats, texts, np.array(ts), np.array(sig), np.array(err), matcher, stop_s)


def write_folder(folder: Path, images: Sequence[np.ndarray | bytes], rate_hz: float = 10.0) -> Path:
    """A KITTI image_02-style folder: timestamps.txt (frame i at i / rate_hz s) and data/%010d.png, each an
    image written by OpenCV (RGB array) or raw bytes written as they are (a corrupt file)."""
    (folder / "data").mkdir(parents=True, exist_ok=True)
    lines = []
    for i, img in enumerate(images):
        path = folder / "data" / f"{i:010d}.png"
        if isinstance(img, bytes):
            path.write_bytes(img)
        else:
            cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        stamp = datetime(2011, 9, 26, 13, 0, 0) + timedelta(seconds=i / rate_hz)
        lines.append(stamp.strftime("%Y-%m-%d %H:%M:%S.%f") + "000")
    (folder / "timestamps.txt").write_text("\n".join(lines) + ("\n" if lines else ""))
    return folder


def noise_image(seed: int, width: int = 160, height: int = 120) -> np.ndarray:
    """A textured RGB uint8 image (uniform noise, a different one per seed)."""
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def write_geotiff(path: Path, origin: Origin, half_m: float = 200.0, res_m: float = 0.5, seed: int = 0) -> Path:
    """A 3-band uint8 textured GeoTIFF in the origin's UTM zone, the square of +-half_m metres about it."""
    size = int(round(2 * half_m / res_m))
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.integers(0, 256, (size, size, 3), dtype=np.uint8), (5, 5), 0)
    transform = rasterio.Affine(res_m, 0.0, origin.utm[0] - half_m, 0.0, -res_m, origin.utm[1] + half_m)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=3, dtype="uint8",
                       crs=f"EPSG:{origin.projector.epsg}", transform=transform) as dst:
        dst.write(np.transpose(img, (2, 0, 1)))
    return path
