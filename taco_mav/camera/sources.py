"""Camera sources for the daemon: OpenCV VideoCapture (device index, video file, RTSP URL, GStreamer pipeline),
an image folder with timestamps (KITTI `image_02`), and sources registered by scheme: `world:DIR`, which renders
a synthetic world at the simulator's true pose (SIMSTATE) for simulation, is registered by
`taco_mav.datasets.synthetic` (importing it registers the scheme; this module never imports datasets).

Every source answers `frame_near(t, max_gap_s) -> (t_frame, RGB uint8 (H, W, 3)) | None`, or with `grey=True`
the frame as grey uint8 (H, W) (camera speed needs no colour: a JPEG's own luma, decoded without its colour
planes, 1.6 ms a 1280x720 frame against 3.4 ms in RGB; a colour frame converted with the RGB weights, as
`cv2.COLOR_RGB2GRAY` converts the RGB frame). Times are seconds on the source's `clock`: the companion's
monotonic clock for live cameras (stamped at grab), the autopilot clock for the folder (frame i at
stamp_i - stamp_0 + offset) and world sources (the autopilot time of the SIMSTATE pose). The daemon maps query
capture times onto that clock before asking.

Spec strings (`--camera`): "SCHEME:BODY" of a registered scheme (`register_camera_scheme`; "world:DIR"),
"folder:DIR[@OFFSET_S]" or an existing directory, "0" (device index), a video file, "rtsp://..." (any
"scheme://" URL), or a GStreamer pipeline (contains "!"). Any other "word:" prefix is refused with a
ConfigError naming the spec (a typo, or a scheme whose package was not imported).

`FrameGuard` vets what a source returns before it reaches a matcher: missing, stale (frame time far from the
capture time), corrupt (unreadable file), wrong shape, blank (uniform: lens cap, dead sensor) and frozen
(bit-identical to the previous frame at another time) frames are rejected with `FrameRejected(reason)`. With a
`FrameRectifier` it also undistorts frames and rescales frames of another size with the model's aspect (the one
place frames are rectified, `taco_mav.camera.calibration`), refuses a source of another aspect at start-up
(`check_source`), and may watch the horizon against the profile's pitch (`taco_mav.camera.horizon`).
"""

from __future__ import annotations

import bisect
import enum
import logging
import math
import re
import threading
import time
import zlib
from collections import deque
from pathlib import Path
from typing import Callable, Protocol

import cv2
import numpy as np

from taco_mav.camera.calibration import FrameRectifier, LensCalibration
from taco_mav.camera.geometry import GroundCamera
from taco_mav.camera.horizon import HorizonCheck, HorizonWarning
from taco_mav.errors import ConfigError, DataError

log = logging.getLogger(__name__)

__all__ = ["CameraFactory", "CameraSource", "ClockDomain", "FolderSource", "FrameGuard", "FrameRejected",
           "VideoSource", "camera_schemes", "open_camera", "register_camera_scheme", "unregister_camera_scheme"]

FRAME_REJECT_REASONS = ("no_frame", "stale_frame", "corrupt_frame", "bad_shape", "blank_frame", "frozen_frame")


class FrameRejected(Exception):
    """A camera frame that must not reach the matcher. reason: one of FRAME_REJECT_REASONS; detail: text."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail = reason, detail


class ClockDomain(enum.Enum):
    """Which clock a source's timestamps are on."""

    COMPANION = "companion"
    AUTOPILOT = "autopilot"


class CameraSource(Protocol):
    """A camera. `needs_pose` sources want `feed_pose(t_autopilot, lat, lon, yaw_ned)` calls (world:);
    `noiseless` sources render a model, so bit-identical frames at different times are legitimate there;
    `mosaic_path`: the GeoTIFF a simulated source renders from, the daemon's default satellite map (None for
    real cameras)."""

    clock: ClockDomain
    needs_pose: bool
    noiseless: bool
    mosaic_path: Path | None

    def start(self) -> None: ...

    def close(self) -> None: ...

    def frame_near(self, t: float, max_gap_s: float, grey: bool = False) -> tuple[float, np.ndarray] | None: ...

    def frame_size(self) -> tuple[int, int] | None:
        """(width, height) px of the frames, when known before the first frame (after `start`)."""
        ...


class VideoSource:
    """OpenCV VideoCapture in a thread; the last `ring` frames are kept with their grab time (companion clock).
    Files are paced at their frame rate; devices and streams are reopened after failures (1 s back-off).

    Frames are kept as they come and converted (and, for MJPEG, decoded) only when asked for (`frame_near`): a
    consumer uses a few frames a second of a 30 fps camera (fixes, camera speed, recording), so the grab thread
    does not decode or convert the rest. An MJPEG stream (a USB camera's usual format, an MJPG video file) is
    read undecoded where OpenCV can hand over its JPEG frames (the V4L2 backend with CONVERT_RGB off, the FFmpeg
    backend with CAP_PROP_FORMAT -1; a GStreamer pipeline ending in image/jpeg hands them over encoded by itself)
    and each frame asked for is decoded with `cv2.imdecode` (straight to RGB where OpenCV can), which is what
    OpenCV's V4L2 backend decodes MJPEG with; anything else is decoded as it is grabbed, as before. A JPEG that
    does not decode is a `FrameRejected("corrupt_frame")`. `encoded`: whether frames are kept undecoded."""

    clock = ClockDomain.COMPANION
    needs_pose = False
    noiseless = False
    mosaic_path: Path | None = None

    def __init__(self, spec: str, ring: int = 30, clock=time.monotonic) -> None:
        self.spec = spec
        self._clock = clock
        # (grab time, frame as grabbed: BGR or grey image, or JPEG bytes (1, N) uint8)
        self._frames: deque[tuple[float, np.ndarray]] = deque(maxlen=ring)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="taco-camera", daemon=True)
        self.is_file = Path(spec).is_file()
        self.grabbed = 0
        self.failures = 0
        self.encoded = False
        self._size: tuple[int, int] | None = None
        # the last frame handed out in each form (RGB, grey), which consumers share
        self._decoded: dict[bool, tuple[float, np.ndarray]] = {}

    def _open(self) -> cv2.VideoCapture:
        if self.spec.isdigit():
            cap = cv2.VideoCapture(int(self.spec))
        elif "!" in self.spec:
            cap = cv2.VideoCapture(self.spec, cv2.CAP_GSTREAMER)
        else:
            cap = cv2.VideoCapture(self.spec)
        self.encoded = cap.isOpened() and _keep_jpeg(cap)
        return cap

    def start(self) -> None:
        cap = self._open()
        if not cap.isOpened():
            raise ConfigError(f"--camera {self.spec!r}: OpenCV cannot open it")
        self._cap = cap
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0)
        self._size = (w, h) if w > 0 and h > 0 else None  # some backends tell only after the first frame
        log.info("camera %s: %s, %s", self.spec, f"{w}x{h} px" if self._size else "size unknown",
                 "MJPEG kept undecoded until used" if self.encoded else "decoded as grabbed")
        self._thread.start()

    def frame_size(self) -> tuple[int, int] | None:
        return self._size

    def _run(self) -> None:
        cap = self._cap
        period = 0.0
        if self.is_file:
            fps = cap.get(cv2.CAP_PROP_FPS)
            period = 1.0 / fps if fps and math.isfinite(fps) and fps > 0 else 0.1
        next_t = self._clock()
        while not self._stop.is_set():
            ok, frame = cap.read()
            t = self._clock()
            if not ok or frame is None or frame.size == 0:
                self.failures += 1
                cap.release()
                if self.is_file:
                    log.info("camera %s: end of file", self.spec)
                    return
                log.warning("camera %s: read failed; reopening in 1 s", self.spec)
                if self._stop.wait(1.0):
                    return
                cap = self._open()
                continue
            with self._lock:
                self._frames.append((t, frame))
            self.grabbed += 1
            self.encoded = self.encoded or _jpeg(frame)  # GStreamer's image/jpeg too
            if period:
                next_t += period
                self._stop.wait(max(0.0, next_t - self._clock()))
        cap.release()

    def frame_near(self, t: float, max_gap_s: float, grey: bool = False) -> tuple[float, np.ndarray] | None:
        """(grab time, RGB uint8 (H, W, 3), or grey (H, W) with `grey`) of the kept frame nearest t, or None when
        none is within max_gap_s; FrameRejected("corrupt_frame") for a JPEG that does not decode."""
        with self._lock:
            if not self._frames:
                return None
            best_t, raw = min(self._frames, key=lambda f: abs(f[0] - t))
            done = self._decoded.get(grey)
        if abs(best_t - t) > max_gap_s:
            return None
        if done is not None and done[0] == best_t:
            return done
        out = (best_t, _to_grey(raw) if grey else _to_rgb(raw))
        with self._lock:
            self._decoded[grey] = out
        return out

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)


def _keep_jpeg(cap: cv2.VideoCapture) -> bool:
    """Ask an MJPEG capture for its frames undecoded (JPEG bytes); True when the backend agreed. Backends
    other than V4L2 and FFmpeg, and other codecs, are left decoding as they grab."""
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC) or 0)
    if fourcc != cv2.VideoWriter_fourcc(*"MJPG"):
        return False
    backend = cap.getBackendName()
    if backend == "V4L2":
        return bool(cap.set(cv2.CAP_PROP_CONVERT_RGB, 0))
    if backend == "FFMPEG":
        return bool(cap.set(cv2.CAP_PROP_FORMAT, -1))
    return False


# OpenCV >= 4.10 decodes a JPEG straight to RGB (libjpeg's own colour conversion, the same pixels as BGR then
# swapped, checked on 100 frames of the companion bench's video): 3.4 ms a 1280x720 frame instead of 5.9 ms with
# the BGR image and its RGB copy (two fresh 2.7 MB arrays). Older builds decode to BGR and convert.
_IMREAD_RGB: int | None = getattr(cv2, "IMREAD_COLOR_RGB", None)


def _jpeg(frame: np.ndarray) -> bool:
    """Whether a grabbed frame is an undecoded MJPEG frame (its JPEG bytes as one row of uint8)."""
    return frame.ndim == 2 and frame.shape[0] == 1


def _decode(jpeg: np.ndarray, flags: int) -> np.ndarray:
    """An undecoded MJPEG frame decoded with imdecode `flags`; FrameRejected("corrupt_frame") when it does not."""
    img = cv2.imdecode(jpeg, flags)
    if img is None:
        raise FrameRejected("corrupt_frame", "a JPEG frame from the camera does not decode")
    return img


def _to_rgb(frame: np.ndarray) -> np.ndarray:
    """A grabbed frame (BGR or grey image, or JPEG bytes as one row of uint8) as RGB uint8 (H, W, 3)."""
    if _jpeg(frame):
        if _IMREAD_RGB is not None:
            return _decode(frame, _IMREAD_RGB)
        return cv2.cvtColor(_decode(frame, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB) if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)


def _to_grey(frame: np.ndarray) -> np.ndarray:
    """A grabbed frame (BGR or grey image, or JPEG bytes as one row of uint8) as grey uint8 (H, W): a JPEG's luma
    plane (its colour planes are not decoded), a BGR image with the RGB weights (`cv2.COLOR_BGR2GRAY`)."""
    if _jpeg(frame):
        return _decode(frame, cv2.IMREAD_GRAYSCALE)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame


class FolderSource:
    """Timestamped images: DIR/timestamps.txt + DIR/data/*.png (KITTI image_02), or a drive folder holding
    image_02: frame i is at (stamp_i - stamp_0) + offset_s on the autopilot clock. Or a recording
    (`taco-mav run --record`): DIR/frames.csv names each frame with its capture time on the recorded autopilot
    clock, where it is played (+ offset_s). Images load on demand."""

    clock = ClockDomain.AUTOPILOT
    needs_pose = False
    noiseless = False
    mosaic_path: Path | None = None

    def __init__(self, folder: str | Path, offset_s: float = 0.0) -> None:
        from taco_mav.timestamps import read_timestamps

        folder = Path(folder)
        if (folder / "image_02").is_dir():
            folder = folder / "image_02"
        if (folder / "frames.csv").is_file():
            self.times, self.paths = _recorded_frames(folder / "frames.csv", offset_s)
            return
        stamps = folder / "timestamps.txt"
        if not stamps.is_file():
            raise ConfigError(f"--camera {folder}: no timestamps.txt (expected a KITTI image_02 folder)")
        ns = read_timestamps(stamps)
        self.paths = sorted((folder / "data").glob("*.png")) or sorted((folder / "data").glob("*.jpg"))
        if len(self.paths) != len(ns):
            raise DataError(f"{folder}: {len(self.paths)} images but {len(ns)} timestamps")
        self.times = list((ns - ns[0]) * 1e-9 + offset_s)

    def frame_size(self) -> tuple[int, int] | None:
        """The first image's size (None when it is unreadable)."""
        bgr = cv2.imread(str(self.paths[0]), cv2.IMREAD_COLOR) if self.paths else None
        return None if bgr is None else (bgr.shape[1], bgr.shape[0])

    def start(self) -> None:
        pass

    def close(self) -> None:
        pass

    def frame_near(self, t: float, max_gap_s: float, grey: bool = False) -> tuple[float, np.ndarray] | None:
        i = bisect.bisect_left(self.times, t)
        best = min((j for j in (i - 1, i) if 0 <= j < len(self.times)), key=lambda j: abs(self.times[j] - t))
        if abs(self.times[best] - t) > max_gap_s:
            return None
        bgr = cv2.imread(str(self.paths[best]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FrameRejected("corrupt_frame", f"{self.paths[best].name} not readable")
        return self.times[best], cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY if grey else cv2.COLOR_BGR2RGB)


def _recorded_frames(index: Path, offset_s: float) -> tuple[list[float], list[Path]]:
    """A recording's frames.csv (`daemon.record`): (autopilot times + offset_s, image paths), in time order; a
    bad line is a DataError naming the file and line."""
    times, paths = [], []
    lines = index.read_text().splitlines()
    if not lines or lines[0].split(",")[:2] != ["index", "t_autopilot_s"]:
        raise DataError(f"{index}: not a frame index (expected the header 'index,t_autopilot_s,...')")
    for n, line in enumerate(lines[1:], start=2):
        cols = line.split(",")
        try:
            t, name = float(cols[1]), cols[3]
        except (IndexError, ValueError):
            raise DataError(f"{index}:{n}: expected index,t_autopilot_s,t_companion_s,file, got {line!r}") from None
        if not math.isfinite(t):
            raise DataError(f"{index}:{n}: t_autopilot_s is {cols[1]}")
        times.append(t + offset_s)
        paths.append(index.parent / name)
    if not times:
        raise DataError(f"{index}: no frames")
    order = sorted(range(len(times)), key=times.__getitem__)
    return [times[i] for i in order], [paths[i] for i in order]


class FreezeWatch:
    """Whether a camera's picture has stopped changing, shared by the frame guards of its consumers (the matcher's
    and the camera-speed loop's, each in its own thread and at its own rate). A guard that sees one picture at two
    frame times marks the camera frozen since the first; until that guard sees the picture change, every guard
    refuses frames stamped after that time. The matcher, one frame every few seconds, never sees a repeat of its
    own: without the shared watch, a hung camera's picture, 1 s old and stamped now, is a fix 3 m behind the rover
    (SITL, docs/sitl.md). Times are frame times on the source's clock, s."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._since: dict[int, float] = {}  # guard id -> frozen since, s

    def repeated(self, guard: object, since: float) -> None:
        """`guard` saw the picture of frame time `since` again."""
        with self._lock:
            self._since.setdefault(id(guard), since)

    def changed(self, guard: object) -> None:
        """`guard` saw the picture change: its mark (if any) is lifted."""
        with self._lock:
            self._since.pop(id(guard), None)

    def frozen_since(self) -> float | None:
        """The earliest frame time from which some guard still sees one picture, s; None: not frozen."""
        with self._lock:
            return min(self._since.values(), default=None)


class FrameGuard:
    """Vets frames for one camera (used from one thread: the matcher worker). width, height: the camera model's
    image size, px; max_gap_s: largest |frame time - capture time| accepted, s; min_std: a frame whose grey
    levels vary less than this (std over a subsample, 0-255) is blank; check_frozen: reject a frame identical
    (CRC-32 of all pixels) to the previous one but stamped at another time (False for noiseless sources);
    rectifier: undistorts and rescales raw frames to the model (None: frames must be the model's size already);
    horizon: checks each passed frame's horizon against the profile's pitch (warnings: `take_warnings`);
    grey: the consumer's frames are grey uint8 (H, W), asked for with `frame_near(..., grey=True)` (camera speed);
    freeze: the camera's `FreezeWatch`, shared with its other consumers' guards (with check_frozen)."""

    def __init__(self, width: int, height: int, max_gap_s: float, min_std: float = 2.0,
                 check_frozen: bool = True, rectifier: FrameRectifier | None = None,
                 horizon: HorizonCheck | None = None, grey: bool = False, freeze: FreezeWatch | None = None) -> None:
        self.width, self.height, self.max_gap_s, self.grey = int(width), int(height), float(max_gap_s), grey
        self.min_std, self.check_frozen = float(min_std), check_frozen
        self.rectifier, self.horizon, self.freeze = rectifier, horizon, freeze
        self._last: tuple[float, int] | None = None  # (frame time s, CRC-32) of the last frame passed

    def _shape_ok(self, img: object) -> bool:
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.shape[2:] != (() if self.grey else (3,)):
            return False
        if self.rectifier is not None:
            return self.rectifier.accepts(img.shape[1], img.shape[0])
        return img.shape[:2] == (self.height, self.width)

    def check_source(self, source: CameraSource, name: str = "camera") -> None:
        """At start-up: ConfigError (one line naming both sizes) when the source's frames cannot be scaled to
        the camera model (another aspect ratio). Sources that tell their size only later are checked per frame."""
        size = source.frame_size()
        if size is None:
            return
        if self.rectifier is not None:
            self.rectifier.check_size(size[0], size[1], name)
        elif size != (self.width, self.height):
            raise ConfigError(f"{name}: frames are {size[0]}x{size[1]} px but the camera model is "
                              f"{self.width}x{self.height} px")

    def check(self, got: tuple[float, np.ndarray] | None, t: float) -> tuple[float, np.ndarray]:
        """(frame time, RGB uint8 (height, width, 3) of the camera model, grey (height, width) for a `grey`
        guard) of a frame nearest capture time t (s, the source's clock), or FrameRejected with the reason."""
        if got is None:
            raise FrameRejected("no_frame")
        t_frame, img = got
        if not math.isfinite(t_frame) or abs(t_frame - t) > self.max_gap_s:
            raise FrameRejected("stale_frame", f"frame {t_frame - t:+.3f} s from the capture time")
        if not self._shape_ok(img):
            shape = getattr(img, "shape", None)
            scaled = " or the same aspect" if self.rectifier is not None else ""
            raise FrameRejected("bad_shape", f"{shape} {getattr(img, 'dtype', type(img).__name__)}, expected "
                                             f"({self.height}, {self.width}{'' if self.grey else ', 3'}){scaled} uint8")
        # the grey levels of every 4th pixel of every 4th row, all channels as one (numpy's std, 1.5 ms a 1280x720
        # frame; OpenCV's sums 0.5 ms, the same value to 1e-12)
        mean, std = cv2.meanStdDev(np.ascontiguousarray(img[::4, ::4]).reshape(-1, 1))
        if float(std[0, 0]) < self.min_std:
            raise FrameRejected("blank_frame", f"mean grey {float(mean[0, 0]):.0f}")
        if self.check_frozen:  # a CRC of all pixels: only where it is compared
            crc = zlib.crc32(np.ascontiguousarray(img).data)
            last, self._last = self._last, (t_frame, crc)
            if last is not None and last[1] == crc and last[0] != t_frame:
                if self.freeze is not None:
                    self.freeze.repeated(self, last[0])
                raise FrameRejected("frozen_frame", f"identical to the frame at {last[0]:.3f} s")
            if self.freeze is not None:
                if last is not None:
                    self.freeze.changed(self)
                since = self.freeze.frozen_since()
                if since is not None and t_frame > since:
                    raise FrameRejected("frozen_frame", f"the camera's picture has not changed since {since:.3f} s")
        if self.rectifier is not None:
            img = self.rectifier(img)
        if self.horizon is not None:
            self.horizon.observe(img)
        return t_frame, img

    def take_warnings(self) -> list[HorizonWarning]:
        """Horizon warnings queued since the last call (for the loop thread: event log and STATUSTEXT)."""
        return self.horizon.take_warnings() if self.horizon is not None else []


CameraFactory = Callable[[str, GroundCamera, LensCalibration | None], CameraSource]
"""Makes a source from a spec's body (after "SCHEME:"), the camera model and the profile's lens (or None)."""

_SCHEMES: dict[str, CameraFactory] = {}
# where the schemes this module knows of are registered, for the error when one is used unregistered
_SCHEME_HOMES = {"world": "taco_mav.datasets.synthetic"}
_SCHEME_RE = re.compile(r"([A-Za-z][A-Za-z0-9_+.-]+):(?!//)")  # "word:" (not "C:", not "rtsp://")


def register_camera_scheme(scheme: str, factory: CameraFactory) -> None:
    """`open_camera("SCHEME:BODY", camera, lens)` returns `factory(BODY, camera, lens)` from now on (again
    registering a scheme replaces its factory). "folder" is built in and cannot be replaced."""
    if not _SCHEME_RE.fullmatch(f"{scheme}:") or scheme == "folder":
        raise ValueError(f"camera scheme {scheme!r}: must be a word of 2+ letters/digits, not 'folder'")
    _SCHEMES[scheme] = factory


def unregister_camera_scheme(scheme: str) -> CameraFactory | None:
    """Forget a scheme; returns its factory (None when it was not registered)."""
    return _SCHEMES.pop(scheme, None)


def camera_schemes() -> tuple[str, ...]:
    """The registered schemes, sorted."""
    return tuple(sorted(_SCHEMES))


def open_camera(spec: str, camera: GroundCamera, lens: LensCalibration | None = None) -> CameraSource:
    """A camera source from a `--camera` spec (see the module docstring); lens: a registered source (world:)
    renders through it (the profile's calibration)."""
    scheme = _SCHEME_RE.match(spec)
    if scheme and scheme.group(1) in _SCHEMES:
        return _SCHEMES[scheme.group(1)](spec[scheme.end():], camera, lens)
    if spec.startswith("folder:") or (Path(spec).is_dir()):
        body = spec[len("folder:"):] if spec.startswith("folder:") else spec
        path, _, offset = body.partition("@")
        try:
            return FolderSource(path, float(offset) if offset else 0.0)
        except ValueError:
            raise ConfigError(f"--camera {spec!r}: offset after '@' must be seconds") from None
    if scheme and "!" not in spec and not Path(spec).exists():  # not a pipeline, not a file named "x:y"
        name = scheme.group(1)
        known = ", ".join(f"{s}:" for s in ("folder", *camera_schemes()))
        if name in _SCHEME_HOMES:
            raise ConfigError(f"--camera {spec!r}: camera scheme '{name}:' is not registered (import "
                              f"{_SCHEME_HOMES[name]} first, which registers it; registered: {known})")
        raise ConfigError(f"--camera {spec!r}: unknown camera scheme '{name}:' (known: {known}, or a device "
                          "index, video file, URL or GStreamer pipeline)")
    return VideoSource(spec)
