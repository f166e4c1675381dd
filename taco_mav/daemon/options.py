"""What a daemon run is told (`DaemonOptions`, from the command line, and `resolve` against the profile) and
what it counts (`DaemonStats`)."""

from __future__ import annotations

import dataclasses
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path

from taco_mav.config import Estimator, Profile
from taco_mav.daemon.record import RecordOptions
from taco_mav.errors import ConfigError
from taco_mav.mavlink.decoders import IMU_MESSAGES


@dataclass(frozen=True)
class DaemonOptions:
    """connect: pymavlink connection string; camera: `--camera` spec; map_path: satellite GeoTIFF (default:
    the world's mosaic for world: cameras); log_dir: tlog + JSONL events + resolved config; origin: (lat, lon,
    alt) start fix instead of the first GPS_RAW_INT; matcher_latency_s: hold each answer until the
    autopilot clock is this far (s) past its capture time (tests; deterministic in lockstep);
    frame_max_gap_s: largest |frame time - capture time| accepted; link_timeout_s: no message from the
    autopilot for this long (companion clock) is a lost link; matcher_timeout_s: a matcher call running longer
    (wall s) is cancelled and its worker replaced."""

    connect: str
    camera: str | None = None
    map_path: Path | None = None
    log_dir: Path | None = None
    origin: tuple[float, float, float] | None = None
    estimator: Estimator | None = None  # None: the profile's
    matcher_latency_s: float = 0.0
    frame_max_gap_s: float = 0.15
    link_timeout_s: float | None = None  # None: the profile's link.timeout_s
    matcher_timeout_s: float | None = None  # None: the profile's map.matcher_timeout_s
    signing_key: Path | None = None  # MAVLink 2 signing key file (32 bytes raw or hex); None = no signing
    record: RecordOptions | None = None  # keep the camera's frames in log_dir/frames (needs log_dir and a camera)
    shadow: bool = False  # run a GNSS-free twin beside the fused filter and report its distance to the receiver


def resolve(profile: Profile, options: DaemonOptions) -> tuple[Profile, DaemonOptions]:
    """The profile with `options.estimator` over its own, and the options with the profile's link and matcher
    timeouts where they give none; ConfigError for a link.imu_message neither 'auto' nor an IMU message."""
    if options.estimator is not None and options.estimator is not profile.estimator:
        profile = dataclasses.replace(profile, estimator=options.estimator)
    if profile.link.imu_message != "auto" and profile.link.imu_message not in IMU_MESSAGES:
        raise ConfigError(f"link.imu_message: {profile.link.imu_message!r} is not 'auto' or one of {IMU_MESSAGES}")
    return profile, dataclasses.replace(
        options,
        link_timeout_s=profile.link.timeout_s if options.link_timeout_s is None else options.link_timeout_s,
        matcher_timeout_s=(profile.map.matcher_timeout_s if options.matcher_timeout_s is None
                           else options.matcher_timeout_s))


@dataclass
class DaemonStats:
    """Counters and timings. imu_to_estimate_s: per IMU sample, receive -> Localiser updated (perf_counter s);
    output_times: monotonic send time of each position output (first configured message)."""

    imu_samples: int = 0
    imu_to_estimate_s: deque[float] = field(default_factory=lambda: deque(maxlen=50_000))
    output_times: deque[float] = field(default_factory=lambda: deque(maxlen=50_000))
    queries: int = 0
    fixes: Counter[str] = field(default_factory=Counter)
    dropped: Counter[str] = field(default_factory=Counter)
    reboots: int = 0
    imu_gaps: int = 0
    attitude_stale: int = 0  # IMU samples paired with an attitude older than imu_source.ATTITUDE_STALE_S
