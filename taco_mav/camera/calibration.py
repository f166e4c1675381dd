"""Lens calibration: the calibration file (read and write), the undistorted pinhole model the IPM uses, and the
per-frame rectification (undistortion and rescaling with a precomputed map) in front of the matcher.

Frames and units: image pixels (u, v) = (column, row), OpenCV's convention (pixel centres at integers);
normalised image coordinates (x, y) = (X / Z, Y / Z) in the camera frame (x right, y down, z forward).
Lens models are OpenCV's: "plumb_bob" (`cv2.undistortPoints`: k1, k2, p1, p2[, k3[, k4, k5, k6]]) and "fisheye"
(`cv2.fisheye`: the equidistant model, k1..k4).

Files (`camera.calibration` in a profile; `taco-mav calibrate` writes the first kind):
- OpenCV FileStorage YAML ("!!opencv-matrix" tags): camera_matrix, distortion_coefficients (opencv-matrix),
  image_width, image_height, and optionally distortion_model ("plumb_bob" or "fisheye"; default plumb_bob).
- ROS camera_info YAML: image_width, image_height, camera_matrix {rows, cols, data}, distortion_model
  (plumb_bob, rational_polynomial, equidistant or fisheye), distortion_coefficients {rows, cols, data}. The
  rectification and projection matrices are ignored (a monocular camera).

The camera model of a profile with a calibration is the undistorted pinhole `pinhole_matrix` gives: the same
image size, every pixel seeing through the lens (no black border), scaled to the profile's width_px x height_px
when those are given. `FrameRectifier` turns raw frames of any size with the calibration's aspect into frames
of that model with one `cv2.remap`.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import cv2
import numpy as np
import yaml

from taco_mav.errors import ConfigError

if TYPE_CHECKING:
    from taco_mav.config.sensors import CameraConfig

log = logging.getLogger(__name__)

__all__ = ["FrameRectifier", "LensCalibration", "LensModel", "aspect_matches", "load_calibration", "pinhole_matrix",
           "resolve_calibration", "scale_matrix", "write_calibration"]

ASPECT_TOLERANCE = 0.01  # frames whose width/height ratio is within 1 % of the model's are rescaled, not refused
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
_MODEL_NAMES = {"plumb_bob": "plumb_bob", "rational_polynomial": "plumb_bob", "radtan": "plumb_bob",
                "equidistant": "fisheye", "fisheye": "fisheye", "kannala_brandt": "fisheye"}
_PLUMB_BOB_COUNTS = (0, 4, 5, 8, 12, 14)


class LensModel(enum.Enum):
    """OpenCV's lens distortion models."""

    PLUMB_BOB = "plumb_bob"
    FISHEYE = "fisheye"


@dataclass(frozen=True)
class LensCalibration:
    """A calibrated camera. K: 3x3 intrinsics, px; D: distortion coefficients (OpenCV order for `model`);
    width, height: the calibrated image size, px; path: the file it came from ("" when built in code)."""

    K: np.ndarray
    D: np.ndarray
    model: LensModel
    width: int
    height: int
    path: str = ""

    def scaled(self, width: int, height: int) -> "LensCalibration":
        """The same lens for frames resized to width x height px (distortion is in normalised coordinates,
        so only K changes)."""
        K = scale_matrix(self.K, (self.width, self.height), (width, height))
        return dataclasses.replace(self, K=K, width=int(width), height=int(height))

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Raw pixels (N, 2) -> normalised image coordinates (N, 2) (iterative inverse of the lens model)."""
        pts = np.ascontiguousarray(np.asarray(uv, np.float64).reshape(-1, 1, 2))
        if self.model is LensModel.FISHEYE:
            out = cv2.fisheye.undistortPoints(pts, self.K, self.D, criteria=_UNDISTORT_CRITERIA)
        else:
            out = cv2.undistortPoints(pts, self.K, self.D, criteria=_UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised image coordinates (N, 2) -> raw pixels (N, 2) (the lens model, closed form)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if self.model is LensModel.FISHEYE:
            return cv2.fisheye.distortPoints(np.ascontiguousarray(xy.reshape(-1, 1, 2)), self.K, self.D).reshape(-1, 2)
        xyz = np.ascontiguousarray(np.c_[xy, np.ones(len(xy))].reshape(-1, 1, 3))
        uv, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), self.K, self.D)
        return uv.reshape(-1, 2)


def scale_matrix(K: np.ndarray, from_size: tuple[int, int], to_size: tuple[int, int]) -> np.ndarray:
    """Intrinsics (3x3, px) of an image of from_size = (width, height) px resized to to_size: focal lengths
    scale with the size, principal points as pixel centres (c + 0.5) s - 0.5."""
    sx, sy = to_size[0] / from_size[0], to_size[1] / from_size[1]
    K = np.array(K, dtype=np.float64)
    return np.array([[K[0, 0] * sx, K[0, 1] * sx, (K[0, 2] + 0.5) * sx - 0.5],
                     [0.0, K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5], [0.0, 0.0, 1.0]])


def aspect_matches(a: tuple[int, int], b: tuple[int, int], tol: float = ASPECT_TOLERANCE) -> bool:
    """Whether sizes a and b = (width, height) px have the same width/height ratio within `tol` (relative)."""
    ra, rb = a[0] / a[1], b[0] / b[1]
    return abs(ra - rb) <= tol * rb


def _border(width: int, height: int, step: float = 4.0) -> dict[str, np.ndarray]:
    """Pixels along each image edge, (N, 2) per edge name."""
    us = np.linspace(0.0, width - 1.0, max(2, int(width / step)))
    vs = np.linspace(0.0, height - 1.0, max(2, int(height / step)))
    return {"left": np.c_[np.zeros_like(vs), vs], "right": np.c_[np.full_like(vs, width - 1.0), vs],
            "top": np.c_[us, np.zeros_like(us)], "bottom": np.c_[us, np.full_like(us, height - 1.0)]}


def pinhole_matrix(lens: LensCalibration) -> np.ndarray:
    """Intrinsics (3x3, px) of the undistorted pinhole image at the calibration's size: the largest view in
    which every pixel sees through the lens (no border), keeping fx/fy, centred on that view."""
    edges = {k: lens.undistort(v) for k, v in _border(lens.width, lens.height).items()}
    x_lo, x_hi = float(edges["left"][:, 0].max()), float(edges["right"][:, 0].min())
    y_lo, y_hi = float(edges["top"][:, 1].max()), float(edges["bottom"][:, 1].min())
    if not (x_hi > x_lo and y_hi > y_lo and all(np.isfinite(e).all() for e in edges.values())):
        raise ConfigError(f"{lens.path or 'lens'}: key distortion_coefficients: the distortion folds the image over")
    fx, fy = float(lens.K[0, 0]), float(lens.K[1, 1])
    lam = max((lens.width - 1.0) / (fx * (x_hi - x_lo)), (lens.height - 1.0) / (fy * (y_hi - y_lo)))
    nfx, nfy = lam * fx, lam * fy
    return np.array([[nfx, 0.0, (lens.width - 1.0) / 2.0 - nfx * (x_lo + x_hi) / 2.0],
                     [0.0, nfy, (lens.height - 1.0) / 2.0 - nfy * (y_lo + y_hi) / 2.0], [0.0, 0.0, 1.0]])


def wide_pinhole(lens: LensCalibration, margin_px: int = 2, max_factor: float = 4.0) -> tuple[np.ndarray, int, int]:
    """A pinhole camera (K 3x3 px, width, height) at the lens's focal length whose view holds the lens's whole
    field of view: what a renderer draws before the lens distortion is applied (`lens_maps`)."""
    pts = np.concatenate(list(_border(lens.width, lens.height, 2.0).values()))
    xy = lens.undistort(pts)
    fx, fy = float(lens.K[0, 0]), float(lens.K[1, 1])
    x0, x1, y0, y1 = xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()
    w = int(math.ceil(fx * (x1 - x0))) + 2 * margin_px + 1
    h = int(math.ceil(fy * (y1 - y0))) + 2 * margin_px + 1
    if not np.isfinite(xy).all() or w > max_factor * lens.width or h > max_factor * lens.height:
        raise ConfigError(f"{lens.path or 'lens'}: key distortion_coefficients: field of view too wide to render "
                          "through a pinhole")
    K = np.array([[fx, 0.0, margin_px - fx * x0], [0.0, fy, margin_px - fy * y0], [0.0, 0.0, 1.0]])
    return K, w, h


def lens_maps(lens: LensCalibration, K_pinhole: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps (float32, lens.height x lens.width) from each raw (distorted) pixel to the pinhole image
    of intrinsics K_pinhole that sees the same ray: remapping a pinhole image with them applies the lens."""
    u, v = np.meshgrid(np.arange(lens.width, dtype=np.float64), np.arange(lens.height, dtype=np.float64))
    xy = lens.undistort(np.c_[u.ravel(), v.ravel()])
    mx = K_pinhole[0, 0] * xy[:, 0] + K_pinhole[0, 1] * xy[:, 1] + K_pinhole[0, 2]
    my = K_pinhole[1, 1] * xy[:, 1] + K_pinhole[1, 2]
    return (mx.reshape(lens.height, lens.width).astype(np.float32),
            my.reshape(lens.height, lens.width).astype(np.float32))


class FrameRectifier:
    """Turns raw camera frames into frames of the camera model (width x height px, intrinsics K): undistorted
    through `lens` (None: a pinhole camera, frames are only resized) and scaled when the frame size differs but
    the aspect matches (the lens's intrinsics scaled with it). One remap per frame; the maps are computed once
    per frame size. `what` names the model in messages (the calibration file or the profile keys)."""

    def __init__(self, width: int, height: int, K: np.ndarray, lens: LensCalibration | None = None,
                 what: str = "camera model") -> None:
        self.width, self.height, self.K = int(width), int(height), np.asarray(K, float)
        self.lens, self.what = lens, what
        self.native = (lens.width, lens.height) if lens is not None else (self.width, self.height)
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._lock = threading.Lock()

    @classmethod
    def from_config(cls, cfg: CameraConfig) -> "FrameRectifier":
        """From a profile's camera section (its calibration file, if any, and the pinhole model fx..height_px)."""
        K = np.array([[cfg.fx, 0.0, cfg.cx], [0.0, cfg.fy, cfg.cy], [0.0, 0.0, 1.0]])
        lens = load_calibration(cfg.calibration) if cfg.calibration else None
        what = f"calibration {cfg.calibration}" if lens else "profile camera.width_px x height_px"
        return cls(cfg.width_px, cfg.height_px, K, lens, what)

    def accepts(self, width: int, height: int) -> bool:
        """Whether frames of width x height px can be turned into model frames."""
        return width > 0 and height > 0 and aspect_matches((width, height), self.native)

    def check_size(self, width: int, height: int, source: str = "camera") -> None:
        """ConfigError (one line naming both sizes) unless frames of width x height px can be used."""
        if not self.accepts(width, height):
            raise ConfigError(f"{source}: frames are {width}x{height} px but the {self.what} is "
                              f"{self.native[0]}x{self.native[1]} px: another aspect ratio "
                              f"({width / height:.3f} vs {self.native[0] / self.native[1]:.3f}), cannot be scaled")

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Raw frame (h, w[, 3]) of an accepted size -> model frame (height, width[, 3]), same dtype."""
        h, w = image.shape[:2]
        if self.lens is None:
            if (w, h) == (self.width, self.height):
                return image
            shrink = w > self.width or h > self.height
            interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
            return cv2.resize(image, (self.width, self.height), interpolation=interp)
        with self._lock:
            maps = self._maps.get((w, h))
            if maps is None:
                maps = self._maps[(w, h)] = self._build(w, h)
                log.info("camera: undistorting %dx%d px frames (%s lens) to %dx%d px", w, h, self.lens.model.value,
                         self.width, self.height)
        return cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _build(self, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
        assert self.lens is not None
        lens = self.lens.scaled(w, h) if (w, h) != self.native else self.lens
        size = (self.width, self.height)
        if lens.model is LensModel.FISHEYE:
            return cv2.fisheye.initUndistortRectifyMap(lens.K, lens.D, np.eye(3), self.K, size, cv2.CV_16SC2)
        return cv2.initUndistortRectifyMap(lens.K, lens.D, None, self.K, size, cv2.CV_16SC2)


# ---------------------------------------------------------------------------------------------- files
def _matrix(value: Any, where: str) -> np.ndarray:
    """A matrix from FileStorage (ndarray), a ROS {rows, cols, data} mapping, a nested or a flat list."""
    if isinstance(value, Mapping):
        if "data" not in value:
            raise ConfigError(f"{where}: expected {{rows, cols, data}}, 'data' missing")
        data = value["data"]
        rows, cols = value.get("rows"), value.get("cols")
        try:
            arr = np.asarray(data, dtype=np.float64)
            if rows is not None and cols is not None:
                arr = arr.reshape(int(rows), int(cols))
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: 'data' must be {rows}x{cols} numbers") from None
        return arr
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected numbers, got {value!r:.60}") from None


def _read_filestorage(path: Path) -> dict[str, Any]:
    """The keys we use from an OpenCV FileStorage file (absent ones omitted)."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except Exception as exc:  # noqa: BLE001 - OpenCV's parser raises cv2.error or SystemError
        detail = (str(exc.__cause__ or exc).strip().splitlines() or ["syntax error"])[-1]
        raise ConfigError(f"{path}: not a readable OpenCV FileStorage file ({detail})") from None
    out: dict[str, Any] = {}
    try:
        for key in ("camera_matrix", "distortion_coefficients", "image_width", "image_height", "distortion_model",
                    "fisheye_model"):
            node = fs.getNode(key)
            if node.empty() or node.isNone():
                continue
            if node.isString():
                out[key] = node.string()
            elif node.isInt() or node.isReal():
                out[key] = node.real()
            elif node.isSeq():
                out[key] = [node.at(i).real() for i in range(node.size())]
            else:
                mat = node.mat()
                out[key] = mat if mat is not None else f"<{key}: not a matrix>"
    finally:
        fs.release()
    return out


def load_calibration(path: str | Path) -> LensCalibration:
    """Read an OpenCV FileStorage or ROS camera_info YAML file; ConfigError naming the file and the key."""
    path = Path(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the calibration file ({exc.strerror})") from None
    if "!!opencv-matrix" in text or text.lstrip().startswith("%YAML:"):
        data = _read_filestorage(path)
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" (line {mark.line + 1})" if mark is not None else ""
            raise ConfigError(f"{path}: not valid YAML{where}") from None
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: expected a mapping with camera_matrix, distortion_coefficients, "
                              "image_width, image_height")
    for key in ("camera_matrix", "image_width", "image_height"):
        if key not in data:
            raise ConfigError(f"{path}: key {key} missing")
    size = []
    for key in ("image_width", "image_height"):
        v = data[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v < 1:
            raise ConfigError(f"{path}: key {key}: expected a positive integer, got {v!r}")
        size.append(int(v))
    K = _matrix(data["camera_matrix"], f"{path}: key camera_matrix")
    if K.shape == (9,):
        K = K.reshape(3, 3)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise ConfigError(f"{path}: key camera_matrix: expected a finite 3x3 matrix, got shape {K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise ConfigError(f"{path}: key camera_matrix: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    name = data.get("distortion_model")
    if name is None:
        name = "fisheye" if data.get("fisheye_model") else "plumb_bob"
    if not isinstance(name, str) or name.lower() not in _MODEL_NAMES:
        raise ConfigError(f"{path}: key distortion_model: {name!r} is not one of {', '.join(_MODEL_NAMES)}")
    model = LensModel(_MODEL_NAMES[name.lower()])
    D = _matrix(data.get("distortion_coefficients", []), f"{path}: key distortion_coefficients").ravel()
    counts = (4,) if model is LensModel.FISHEYE else _PLUMB_BOB_COUNTS
    if D.size not in counts or not np.isfinite(D).all():
        raise ConfigError(f"{path}: key distortion_coefficients: {model.value} takes "
                          f"{' or '.join(map(str, counts))} finite numbers, got {D.size}")
    return LensCalibration(K, D.astype(np.float64), model, size[0], size[1], str(path))


def write_calibration(path: str | Path, lens: LensCalibration, extra: Mapping[str, Any] | None = None) -> None:
    """Write an OpenCV FileStorage YAML file (what `load_calibration` and OpenCV read); extra: more scalar
    entries (e.g. avg_reprojection_error)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    try:
        fs.write("image_width", int(lens.width))
        fs.write("image_height", int(lens.height))
        fs.write("distortion_model", lens.model.value)
        fs.write("camera_matrix", np.asarray(lens.K, np.float64))
        fs.write("distortion_coefficients", np.asarray(lens.D, np.float64).reshape(1, -1))
        for key, value in (extra or {}).items():
            fs.write(key, value if isinstance(value, str) else float(value) if isinstance(value, float) else int(value))
    finally:
        fs.release()


def resolve_calibration(cfg: CameraConfig, raw: Mapping[str, Any], base_dir: Path | None, where: str) -> CameraConfig:
    """The camera section with `calibration` resolved (relative to base_dir, the profile's folder) and read:
    fx, fy, cx, cy, width_px, height_px become the undistorted pinhole model (at width_px x height_px when the
    profile gives them, else the calibration's size). raw: the section as written (to tell given keys from
    defaults); where: the profile file, for messages. ConfigError names the file and the key."""
    path = Path(cfg.calibration).expanduser()
    if not path.is_absolute():
        path = (base_dir if base_dir is not None else Path.cwd()) / path
    path = path.resolve()
    if not path.is_file():
        raise ConfigError(f"{where} camera.calibration: {path} not found")
    try:
        lens = load_calibration(path)
        pinhole = pinhole_matrix(lens)
    except ConfigError as exc:
        raise ConfigError(f"{where} camera.calibration: {exc}") from None
    given = [k for k in ("width_px", "height_px") if k in raw]
    if len(given) == 1:
        raise ConfigError(f"{where} camera.{given[0]}: give both width_px and height_px with camera.calibration, "
                          "or neither")
    size = (cfg.width_px, cfg.height_px) if given else (lens.width, lens.height)
    if not aspect_matches(size, (lens.width, lens.height)):
        raise ConfigError(f"{where} camera.width_px: {size[0]}x{size[1]} px has another aspect ratio than the "
                          f"calibration {path} ({lens.width}x{lens.height} px)")
    K = scale_matrix(pinhole, (lens.width, lens.height), size)
    derived = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    for key, value in derived.items():
        if key in raw and not math.isclose(float(raw[key]), value, rel_tol=1e-6, abs_tol=1e-6):
            raise ConfigError(f"{where} camera.{key}: {raw[key]} disagrees with the calibration {path} (its "
                              f"undistorted {key} is {value:.4f}); leave fx, fy, cx, cy out with camera.calibration")
    return dataclasses.replace(cfg, calibration=str(path), width_px=int(size[0]), height_px=int(size[1]),
                               **{k: float(v) for k, v in derived.items()})
