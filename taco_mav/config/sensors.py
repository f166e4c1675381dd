"""Camera, satellite map and matcher sections of a profile."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from taco_mav.config.fields import bounded

__all__ = ["CameraConfig", "ClassicalMatcherConfig", "EmulatorConfig", "Fg2Config", "MapConfig"]


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera looking forward from the vehicle. Defaults: KITTI image_02 (rectified P2)."""

    width_px: int = field(default=1242, metadata=bounded(1))
    height_px: int = field(default=375, metadata=bounded(1))
    fx: float = field(default=721.5377, metadata=bounded(0.0, open_lo=True))
    fy: float = field(default=721.5377, metadata=bounded(0.0, open_lo=True))
    cx: float = 609.5593
    cy: float = 172.854
    mount_height_m: float = field(default=1.65, metadata=bounded(0.0, open_lo=True))  # KITTI cameras: 1.65 m
    pitch_rad: float = field(default=0.0, metadata=bounded(-1.0, 1.0))  # positive = looking down
    # Lens calibration file (OpenCV FileStorage or ROS camera_info YAML, relative to the profile's folder; written
    # by `taco-mav calibrate`). With it frames are undistorted before the matcher and fx, fy, cx, cy, width_px,
    # height_px become that undistorted pinhole model (docs/camera.md); "" = frames are already pinhole.
    calibration: str = ""
    # Lever arm: the camera's optical centre relative to the vehicle reference point (the autopilot's body origin,
    # where its IMU and EKF sit; in KITTI the OXTS unit), body FRD metres [x forward, y right, z down]. Every
    # matcher localises the CAMERA; core/search.py fix_position moves each fix back to the reference point by this
    # offset rotated by the heading (z is not used: flat ground). Measure it on the vehicle (docs/camera.md);
    # KITTI image_02: [1.080, 0.250, -0.729] from the dataset's calibration (datasets/kitti_io.py).
    position_frd_m: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), metadata=bounded(-20.0, 20.0))


@dataclass(frozen=True)
class MapConfig:
    """Satellite crops handed to the matcher (Sec. III-C)."""

    crop_size_px: int = field(default=512, metadata=bounded(16, 4096))
    # Mosaic resolution expected by the matcher, m/px; crops are resampled to it (zoom 19: ~0.3 m/px at
    # Karlsruhe's latitude, Sec. III-C; FG2's KITTI crops are ~0.2 m/px).
    crop_m_per_px: float = field(default=0.2, metadata=bounded(0.0, open_lo=True))
    # A crop with a smaller share of on-map pixels raises OffMapError; above it, off-map pixels are zero and
    # Crop.valid_fraction says how many were on the map (not in the paper).
    min_valid_fraction: float = field(default=0.9, metadata=bounded(0.0, 1.0))
    # Mosaics up to this size (decoded RGBA, MB) are read into memory at open; larger ones are read in cached
    # 256 px blocks (not in the paper).
    in_memory_max_mb: float = field(default=1024.0, metadata=bounded(0.0))
    # A matcher call running longer (wall s) is cancelled, counted, and its worker replaced.
    matcher_timeout_s: float = field(default=10.0, metadata=bounded(0.0, open_lo=True))
    # The mosaic's georeferencing 1-sigma per axis, m: real orthophotos are off by about a metre. taco+ then
    # carries the offset as two filter states that every fix reads (fix = position + offset): it is learnt
    # while the position is anchored tighter than that (the start, a precise GNSS), and its uncertainty stays
    # in the reported accuracy (docs/taco_plus.md, "The map's offset"; 0: the map is taken as exact, as in
    # the paper). Not in the paper.
    georef_sigma_m: float = field(default=0.0, metadata=bounded(0.0, 20.0))


@dataclass(frozen=True)
class ClassicalMatcherConfig:
    """Classical matcher: inverse perspective mapping + FFT correlation (CPU)."""

    bev_size_px: int = field(default=256, metadata=bounded(16, 2048))
    # Matching resolution, m/px (0.6: 0.14 m median error at ~20 ms per five-crop trigger; see docs/matchers.md).
    bev_m_per_px: float = field(default=0.6, metadata=bounded(0.0, open_lo=True))
    max_range_m: float = field(default=40.0, metadata=bounded(1.0))
    rotation_range_rad: float = field(default=math.radians(10.0), metadata=bounded(0.0, math.pi))
    # Rotation grid step; the best grid angle is refined at +-step/2, +-step/4 and by a parabola.
    rotation_step_rad: float = field(default=math.radians(4.0), metadata=bounded(0.0, math.pi, open_lo=True))
    # Dense descriptor the matcher correlates (taco_mav/cvgl/descriptors.py): "orientation" (gradient orientation
    # in doubled-angle form: blind to an edge's polarity, so it survives a camera and a map that disagree on
    # which material is brighter) or "lcn" (grey-level local contrast normalisation: blind to gain and offset only).
    # docs/matchers.md compares them on flat worlds with and without an appearance gap.
    descriptor: str = "orientation"
    # The channel described (cvgl/descriptors.py grey_channel): "luma" (brightness), "unsaturated" (255 - saturation)
    # or "achromatic" (how grey, from Lab chroma). docs/results.md measures each on the real pairs.
    grey: str = "luma"
    # Masks for what inverse perspective mapping cannot represent (taco_mav/cvgl/masks.py): vertical structure
    # (poles, cars, facades: long image-vertical edges, masked from their foot up) and the bottom image rows the
    # ego vehicle hides (its bonnet; 0 for KITTI's camera). taco+'s camera speed (cvgl/ground_motion.py) places its
    # ground band above those rows as well.
    mask_vertical: bool = True
    # Standing vegetation (trees, hedges: green regions that reach the horizon) masked by colour, from their foot
    # up (taco_mav/cvgl/masks.py vegetation_mask); exg_min its least excess-green index. Off by default: on real
    # imagery it does not make the matcher place a view (docs/matchers.md).
    mask_vegetation: bool = False
    vegetation_exg_min: float = field(default=0.05, metadata=bounded(-1.0, 2.0))
    ego_mask_rows: int = field(default=0, metadata=bounded(0))
    # w = 1 / (1 + exp(-(PSR - psr_at_half_weight) / psr_logistic_scale)); None: the descriptor's own calibration
    # (taco_mav/cvgl/classical.py W_CALIBRATION has the measurements; w is set so that the fix noise it implies,
    # paper Sec. III-F, matches the matcher's errors).
    psr_at_half_weight: float | None = field(default=None, metadata=bounded(0.0, open_lo=True))
    psr_logistic_scale: float | None = field(default=None, metadata=bounded(0.0, open_lo=True))
    # Vehicle positions searched: within this many metres of the crop centre along each crop axis.
    search_radius_m: float = field(default=30.0, metadata=bounded(1.0))
    # Shifts where the template overlaps the valid crop by less than this share of its mask are not scored.
    min_overlap: float = field(default=0.6, metadata=bounded(0.0, 1.0, open_lo=True))
    # Local contrast normalisation (both images): Gaussian sigma of the local mean/std, metres.
    lcn_sigma_m: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))
    # Sidelobe for the peak-to-sidelobe ratio: the score map outside this radius around the peak, metres.
    psr_exclusion_m: float = field(default=2.0, metadata=bounded(0.0))


@dataclass(frozen=True)
class EmulatorConfig:
    """FG2-statistics emulator (a statistical model of FG2 on KITTI, not a matcher)."""

    capture_radius_m: float = field(default=20.0, metadata=bounded(0.0, open_lo=True))  # Sec. III-D
    median_error_m: float = field(default=0.51, metadata=bounded(0.0, open_lo=True))  # FG2 KITTI same-area
    mean_error_m: float = field(default=0.75, metadata=bounded(0.0, open_lo=True))
    cross_area_median_error_m: float = field(default=4.15, metadata=bounded(0.0, open_lo=True))  # cross-area
    cross_area_mean_error_m: float = field(default=7.31, metadata=bounded(0.0, open_lo=True))
    cross_area_sequences: tuple[str, ...] = ("00", "06")  # Sec. IV-A
    yaw_noise_rad: float = field(default=0.03, metadata=bounded(0.0))
    symmetric_lock_rate: float = field(default=0.03, metadata=bounded(0.0, 1.0))
    silent_outlier_rate: float = field(default=0.01, metadata=bounded(0.0, 1.0))
    seed: int = 0
    # Not in the paper (emulator shape, see docs/matchers.md): error direction is drawn with lateral/forward
    # spread 2:1 (Sec. III-F's sigma ratio); w = clip(exp(-err / weight_scale_m) + N(0, weight_noise)).
    lateral_to_forward: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))
    weight_scale_m: float = field(default=2.0, metadata=bounded(0.0, open_lo=True))
    weight_noise: float = field(default=0.05, metadata=bounded(0.0))
    outlier_min_error_m: float = field(default=5.0, metadata=bounded(0.0))  # silent outliers: U(this, capture)
    miss_weight_max: float = field(default=0.15, metadata=bounded(0.0, 1.0, open_lo=True))  # outside capture radius
    # Not in the paper: the share of the log-error variance that belongs to the place rather than the query (0:
    # every answer independent, as FG2's per-image figures are published; 1: every answer near one place equally
    # good), correlated over place_length_m (Gaussian kernel). A real matcher is worse in some streets than in
    # others, so answers a few metres apart, and crops of one frame, are not independent (docs/matchers.md).
    place_share: float = field(default=0.0, metadata=bounded(0.0, 1.0))
    place_length_m: float = field(default=20.0, metadata=bounded(0.0, open_lo=True))


@dataclass(frozen=True)
class Fg2Config:
    """FG2 adapter (extra `fg2`): user-provided checkout and checkpoint."""

    checkout: str = ""
    checkpoint: str = ""
    device: str = "auto"  # "auto", "cpu" or "cuda"
    fp16: bool = True  # fp16 autocast on CUDA around the model; the published FG2 keeps its own precisions
    # (docs/matchers.md: DINOv2 fp16 as FG2 does, CVM, camera_k, pose and mass fp32)
    # "module:function" building the model from (checkout, checkpoint, device); imported with the checkout on
    # sys.path. The default shim checks the published FG2 layout (see docs/matchers.md).
    entry: str = "taco_mav.cvgl.fg2.shim:build_model"
    # Fast path of the published FG2 (ground branch once per trigger, heights batched, SDPA in DINOv2, TF32 on
    # CUDA); false runs FG2's own CVM.forward per crop. Same outputs within float tolerance (tests/test_fg2_fast.py).
    fast: bool = True
    # torch.compile DINOv2's forward (CUDA; the first triggers of each input shape compile, which takes a while).
    compile: bool = False
    # Crops warped on the matcher's device: the K heading-up crops of a trigger are resampled from a device copy of
    # the mosaic in one batched bilinear call (taco_mav/cvgl/fg2/device_crops.py) instead of K cv2 warps on the CPU
    # and an upload; same geometry and off-map rules, within ~1 grey level (tests/test_device_crops.py). Not in
    # the paper.
    device_crops: bool = False
