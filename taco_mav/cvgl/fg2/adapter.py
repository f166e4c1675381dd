"""FG2 adapter (extra `fg2`, torch): a thin wrapper turning a cross-view model into a `Matcher`.

The model is any object with this interface (torch tensors, on the model's device):

- `encode_ground(image, ground_from_pixel, pixel_from_level) -> feats`: image (1, 3, H, W) float in [0, 1] RGB;
  ground_from_pixel (1, 3, 3) the flat-ground homography from pixels (u, v, 1) to (forward, left, 1) metres
  (`GroundCamera.image_to_ground`); pixel_from_level (1, 3, 3) = K @ R_pitch, projecting points of the LEVEL
  camera frame (x right, y down, z forward along the ground, metres, origin at the camera) to homogeneous pixels
  (what FG2 calls camera_k, with the mount pitch folded in). Called ONCE per trigger; feats is opaque here.
- `match_aerial(feats, aerial, m_per_px) -> (R_img, t_px, mass)`: aerial (B, 3, S, S) float in [0, 1], the
  heading-up crops; R_img (B, 2, 2) the rotation, in image coordinates (x right, y down), taking image-up to the
  vehicle's estimated heading; t_px (B, 2) the vehicle position in crop pixels (x right, y down) relative to the
  crop centre (S - 1) / 2; mass (B,) the Procrustes correspondence mass in [0, 1].

`load_model(cfg)` builds it through `cfg.entry` ("module:function", called as fn(checkout, checkpoint, device))
with the user's FG2 checkout on sys.path while the entry is imported and called (removed afterwards); the
default entry, `taco_mav.cvgl.fg2.shim`, wraps the published FG2 model. `taco_mav.cvgl.fg2.tiny` is a small
model with the same interface that the tests save and load through the same path. torch is imported lazily:
without it, the package works and only this matcher raises MatcherError.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import math
import sys
import time
from pathlib import Path
from typing import Any, Iterator, Protocol, Sequence, runtime_checkable

import numpy as np

from taco_mav.camera.geometry import GroundCamera
from taco_mav.config import Fg2Config
from taco_mav.core.types import MatchResult
from taco_mav.cvgl.base import Crop, GroundFrame
from taco_mav.errors import MatcherError

log = logging.getLogger(__name__)

MIN_WEIGHT = 1e-3  # w is in (0, 1]: a zero or non-finite mass becomes this


@runtime_checkable
class Tunable(Protocol):
    """A model with a fast path and compilable parts (the published FG2 wrapper); others ignore fg2.fast and
    fg2.compile."""

    def set_fast(self, fast: bool) -> None:
        """Fast path on (True) or the unoptimised published forward (False), same weights."""

    def compile_parts(self) -> None:
        """torch.compile the expensive parts in place."""


def _torch() -> Any:
    try:
        import torch
    except ImportError:
        raise MatcherError("the fg2 matcher needs torch: pip install 'taco_mav[fg2]'") from None
    return torch


def resolve_device(name: str) -> Any:
    """torch.device for "auto" (CUDA when available), "cpu" or "cuda"."""
    torch = _torch()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise MatcherError("fg2.device is 'cuda' but torch sees no CUDA device")
    return torch.device(name)


def load_model(cfg: Fg2Config) -> Any:
    """Import cfg.entry with cfg.checkout on sys.path and build the model from cfg.checkpoint (eval mode); the
    checkout leaves sys.path again once the model is built."""
    checkout, checkpoint = Path(cfg.checkout).expanduser(), Path(cfg.checkpoint).expanduser()
    if not cfg.checkout or not checkout.is_dir():
        raise MatcherError(f"fg2.checkout: FG2 checkout folder {str(checkout)!r} not found")
    if not cfg.checkpoint or not checkpoint.is_file():
        raise MatcherError(f"fg2.checkpoint: checkpoint file {str(checkpoint)!r} not found")
    module_name, _, fn_name = cfg.entry.partition(":")
    if not module_name or not fn_name:
        raise MatcherError(f"fg2.entry: {cfg.entry!r} is not 'module:function'")
    added = str(checkout) not in sys.path
    if added:  # only while the entry is imported and builds the model
        sys.path.insert(0, str(checkout))
    try:
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise MatcherError(f"fg2.entry: cannot import {module_name!r} (checkout {checkout}): {exc}") from None
        build = getattr(module, fn_name, None)
        if build is None:
            raise MatcherError(f"fg2.entry: module {module_name!r} has no {fn_name!r}")
        model = build(checkout, checkpoint, resolve_device(cfg.device))
    finally:
        if added and str(checkout) in sys.path:
            sys.path.remove(str(checkout))
    if hasattr(model, "eval"):
        model.eval()
    log.info("fg2 model %s loaded from %s", type(model).__name__, checkpoint)
    return model


class Fg2Matcher:
    """A `Matcher` around a cross-view model (see the module docstring). model: an already built model; by
    default it is loaded from cfg. camera: the ground camera of the frames."""

    name = "fg2"
    needs_true_pose = False

    def __init__(self, cfg: Fg2Config, camera: GroundCamera, model: Any = None) -> None:
        torch = _torch()
        self.cfg = cfg
        self.camera = camera
        self.model = load_model(cfg) if model is None else model
        params = list(self.model.parameters()) if hasattr(self.model, "parameters") else []
        self.device = params[0].device if params else resolve_device(cfg.device)
        self._cropper: Any = None  # DeviceCropper, made on first use (fg2.device_crops)
        self._ground_from_pixel = torch.as_tensor(camera.image_to_ground, dtype=torch.float32,
                                                  device=self.device)[None]
        self._pixel_from_level = torch.as_tensor(pixel_from_level(camera), dtype=torch.float32,
                                                 device=self.device)[None]
        if isinstance(self.model, Tunable):
            self.model.set_fast(cfg.fast)
            if cfg.compile:
                self.model.compile_parts()
            if self.device.type != "cuda":
                log.warning("fg2.device %r runs on %s: correct but slow (the published FG2 takes minutes per "
                            "trigger on a CPU); set fg2.device: cuda on a machine with a GPU", cfg.device,
                            self.device)
        elif cfg.compile:
            log.warning("fg2.compile: %s has no compilable parts; running it as it is", type(self.model).__name__)
        log.info("fg2: %s on %s, fast path %s, compile %s, fp16 autocast %s, crops warped on %s",
                 type(self.model).__name__, self.device, "on" if cfg.fast else "off", "on" if cfg.compile else "off",
                 "on" if self._autocast_enabled else "off", self.device if self.device_crops else "the CPU")

    @property
    def _autocast_enabled(self) -> bool:
        return bool(self.cfg.fp16 and self.device.type == "cuda")

    def _autocast(self) -> Any:
        torch = _torch()
        return torch.autocast(device_type=self.device.type, dtype=torch.float16, enabled=self._autocast_enabled)

    def match(self, frame: GroundFrame, crops: Sequence[Crop]) -> list[MatchResult]:
        """One MatchResult per crop: the ground image is encoded once, the crops run as one batch."""
        torch = _torch()
        self._check_frame(frame)
        if not crops:
            return []
        sizes = {c.image.shape for c in crops}
        scales = {round(c.m_per_px, 9) for c in crops}
        if len(sizes) != 1 or len(scales) != 1:
            raise MatcherError(f"fg2: crops of one trigger must share size and m/px, got {sizes} and {scales}")

        def aerial() -> Any:
            images = torch.from_numpy(np.stack([c.image for c in crops])).to(self.device)
            return images.permute(0, 3, 1, 2).float() / 255.0

        return self._run(frame, aerial, len(crops), crops[0].m_per_px)

    # ------------------------------------------------------------ crops warped on the device (fg2.device_crops)
    @property
    def device_crops(self) -> bool:
        """The profile switch fg2.device_crops: callers then hand the map and the crop geometry to `cut_crops`
        and `match_crops` (the GeometryMatcher capability, taco_mav/cvgl/fg2/device_crops.py) instead of crops."""
        return bool(getattr(self.cfg, "device_crops", False))

    def cut_crops(self, sat_map: Any, centres_utm: np.ndarray, heading: float, size_px: int,
                  m_per_px: float) -> Any:
        """The K heading-up crops of a trigger resampled on this matcher's device (`DeviceCropper.cut`: same
        geometry and off-map rules as `SatelliteMap.crop`; off-map ones are flagged, not raised)."""
        if self._cropper is None:
            from taco_mav.cvgl.fg2.device_crops import DeviceCropper

            self._cropper = DeviceCropper(self.device)
        with _torch().no_grad():  # not inference_mode: the cropper keeps a mosaic tensor across calls
            return self._cropper.cut(sat_map, centres_utm, heading, size_px, m_per_px)

    def match_crops(self, frame: GroundFrame, crops: Any) -> list[MatchResult]:
        """One MatchResult per present crop of a `DeviceCrops` batch (from `cut_crops`), in order."""
        n = int(crops.images.shape[0])
        if n == 0:
            self._check_frame(frame)
            return []
        return self._run(frame, lambda: crops.images, n, crops.m_per_px)

    def match_geometry(self, frame: GroundFrame, sat_map: Any, centres_utm: np.ndarray, heading: float,
                       size_px: int, m_per_px: float) -> list[MatchResult | None]:
        """cut_crops then match_crops: MatchResults aligned with centres_utm, None where a crop is off the map."""
        crops = self.cut_crops(sat_map, centres_utm, heading, size_px, m_per_px)
        it = iter(self.match_crops(frame, crops))
        return [next(it) if present else None for present in crops.present]

    # ------------------------------------------------------------ the model
    @staticmethod
    def _check_frame(frame: GroundFrame) -> None:
        if frame.image.ndim != 3 or frame.image.shape[2] != 3 or frame.image.size == 0:
            raise MatcherError(f"fg2: ground image must be (H, W, 3) RGB, got shape {frame.image.shape}")

    def _run(self, frame: GroundFrame, aerial_fn: Any, n: int, m_per_px: float) -> list[MatchResult]:
        """Encode the ground once, match the n crops aerial_fn() returns ((n, 3, S, S) float [0, 1] on the
        device) as one batch."""
        torch = _torch()
        self._check_frame(frame)
        start = time.perf_counter()
        with torch.inference_mode(), tf32(self.device.type == "cuda" and self.cfg.fast), self._autocast():
            image = torch.from_numpy(np.ascontiguousarray(frame.image)).to(self.device)
            image = image.permute(2, 0, 1)[None].float() / 255.0
            feats = self.model.encode_ground(image, self._ground_from_pixel, self._pixel_from_level)
            R_img, t_px, mass = self.model.match_aerial(feats, aerial_fn(), m_per_px)
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        elapsed = (time.perf_counter() - start) / n
        R_np = R_img.float().cpu().numpy().reshape(n, 2, 2)
        t_np = t_px.float().cpu().numpy().reshape(n, 2)
        m_np = mass.float().cpu().numpy().reshape(n)
        return [_to_result(R_np[i], t_np[i], float(m_np[i]), m_per_px, elapsed) for i in range(n)]


@contextlib.contextmanager
def tf32(enabled: bool) -> Iterator[None]:
    """TF32 for CUDA matmuls and convolutions while inside (the fast path on CUDA); the flags are restored."""
    if not enabled:
        yield
        return
    torch = _torch()
    saved = torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
    try:
        yield
    finally:
        torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = saved


def pixel_from_level(camera: GroundCamera) -> np.ndarray:
    """3x3 K @ R_pitch: level camera frame (x right, y down, z forward horizontal; metres) -> homogeneous pixels.
    A camera pitched down by p sees a level-frame point X at R_pitch X (rotation about the x axis by p)."""
    c, s = math.cos(camera.pitch_rad), math.sin(camera.pitch_rad)
    return camera.K @ np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _to_result(R_img: np.ndarray, t_px: np.ndarray, mass: float, m_per_px: float, elapsed: float) -> MatchResult:
    """Image-frame (x right, y down) outputs -> MatchResult in the crop's (forward, left) frame.

    (forward, left) = (-y, -x) is a reflection of the image axes, so an image-frame angle a becomes -a.
    """
    if not (np.isfinite(R_img).all() and np.isfinite(t_px).all() and math.isfinite(mass)):
        log.warning("fg2: non-finite model output; returning a zero-weight answer")
        return MatchResult(np.eye(2), np.zeros(2), MIN_WEIGHT, elapsed)
    psi = -math.atan2(R_img[1, 0], R_img[0, 0])
    c, s = math.cos(psi), math.sin(psi)
    t = np.array([-t_px[1] * m_per_px, -t_px[0] * m_per_px])
    w = float(min(max(mass, MIN_WEIGHT), 1.0))
    return MatchResult(np.array([[c, -s], [s, c]]), t, w, elapsed)
