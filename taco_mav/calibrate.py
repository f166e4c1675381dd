"""`taco-mav calibrate`: camera intrinsics and lens distortion from photos of a chessboard (OpenCV).

Board: `board` = (columns, rows) of *inner* corners (a "9x6" board has 10 x 7 squares), `square_m` the side of
one square in metres. Images: every .png/.jpg/.jpeg/.bmp/.tif/.tiff in a folder, all of one size, taken by the
camera at the resolution it will stream, the board filling different parts of the frame (corners included)
at different tilts. Corners: cv2.findChessboardCorners + cv2.cornerSubPix; then cv2.calibrateCamera
(plumb_bob: k1, k2, p1, p2, k3) or cv2.fisheye.calibrate (fisheye: k1..k4). The result is written as OpenCV
FileStorage YAML (`taco_mav.camera.calibration.write_calibration`), the file `camera.calibration` reads.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

from taco_mav.camera.calibration import LensCalibration, LensModel, write_calibration
from taco_mav.errors import ConfigError, DataError

log = logging.getLogger(__name__)

__all__ = ["CalibrationResult", "calibrate", "parse_board"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
MIN_BOARDS = 5  # fewer boards do not constrain five distortion coefficients and four intrinsics
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)


@dataclass(frozen=True)
class CalibrationResult:
    """lens: the calibration; rms_px: RMS reprojection error over every corner, px; images: images read;
    used: names of the images whose board was found; out: the file written."""

    lens: LensCalibration
    rms_px: float
    images: int
    used: tuple[str, ...]
    out: Path


def parse_board(text: str) -> tuple[int, int]:
    """"9x6" -> (9, 6): inner corners per row and per column (each at least 2)."""
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--board: expected COLSxROWS of inner corners, e.g. 9x6, got {text!r}") from None
    if cols < 2 or rows < 2:
        raise ConfigError(f"--board: {text!r}: at least 2x2 inner corners")
    return cols, rows


def _images(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise DataError(f"--images {folder}: not a folder")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not paths:
        raise DataError(f"--images {folder}: no images ({', '.join('*' + s for s in IMAGE_SUFFIXES)})")
    return paths


def _corners(grey: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners (N, 1, 2) float32 of the board in a grey image, or None."""
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(grey, board, flags=flags)
    if not found:
        return None
    # search window: at most 11 px each side, but within half the closest corner spacing (small, tilted boards)
    grid = corners.reshape(board[1], board[0], 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=a), axis=2).min() for a in (0, 1))
    win = int(np.clip(spacing * 0.4, 2, 11))
    return cv2.cornerSubPix(grey, corners, (win, win), (-1, -1), _SUBPIX_CRITERIA)


def _fisheye_flag(name: str) -> int:
    """A cv2.fisheye calibration flag: cv2.fisheye.NAME in OpenCV 4, cv2.NAME (other values) in OpenCV 5."""
    return int(getattr(cv2.fisheye, name, None) or getattr(cv2, name))


def calibrate(images: Path, board: tuple[int, int], square_m: float, out: Path,
              fisheye: bool = False) -> CalibrationResult:
    """Calibrate from the chessboard photos in `images` and write `out` (OpenCV FileStorage YAML). DataError
    for an empty folder, unreadable images, images of different sizes, or fewer than MIN_BOARDS boards found."""
    if not square_m > 0:
        raise ConfigError(f"--square: the side of a square in metres must be positive, got {square_m}")
    paths = _images(Path(images))
    greys, unreadable = [], []
    for p in paths:
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        if img is None:
            unreadable.append(p.name)
        else:
            greys.append((p, img))
    if unreadable:
        raise DataError(f"--images {images}: {len(unreadable)} of {len(paths)} images unreadable: "
                        f"{', '.join(unreadable[:5])}{' ...' if len(unreadable) > 5 else ''}")
    h, w = greys[0][1].shape
    for p, g in greys:
        if g.shape != (h, w):
            raise DataError(f"{p}: {g.shape[1]}x{g.shape[0]} px, but {greys[0][0].name} is {w}x{h} px: "
                            "calibrate one resolution at a time")
    obj = np.zeros((board[0] * board[1], 3), np.float64)
    obj[:, :2] = np.mgrid[0:board[0], 0:board[1]].T.reshape(-1, 2) * square_m
    img_pts, used = [], []
    for p, g in greys:
        c = _corners(g, board)
        log.debug("%s: %s", p.name, "board found" if c is not None else "no board")
        if c is not None:
            img_pts.append(c.astype(np.float64))
            used.append(p.name)
    if len(used) < MIN_BOARDS:
        raise DataError(f"--images {images}: a {board[0]}x{board[1]} chessboard (inner corners) found in "
                        f"{len(used)} of {len(paths)} images; at least {MIN_BOARDS} needed (check --board)")
    try:
        if fisheye:
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
            flags = _fisheye_flag("CALIB_RECOMPUTE_EXTRINSIC") | _fisheye_flag("CALIB_FIX_SKEW")
            rms, K, D, _, _ = cv2.fisheye.calibrate([obj.reshape(1, -1, 3)] * len(img_pts),
                                                    [p.reshape(1, -1, 2) for p in img_pts], (w, h), None, None,
                                                    flags=flags, criteria=crit)
        else:
            rms, K, D, _, _ = cv2.calibrateCamera([obj.astype(np.float32)] * len(img_pts),
                                                  [p.astype(np.float32) for p in img_pts], (w, h), None, None)
    except cv2.error as exc:
        raise DataError(f"--images {images}: OpenCV calibration failed ({str(exc).strip().splitlines()[-1]}); "
                        "take more varied views of the board") from None
    lens = LensCalibration(np.asarray(K, np.float64), np.asarray(D, np.float64).ravel(),
                           LensModel.FISHEYE if fisheye else LensModel.PLUMB_BOB, w, h, str(out))
    write_calibration(out, lens, {
        "calibration_time": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "board_width": board[0], "board_height": board[1], "square_size": float(square_m),
        "nr_of_frames": len(used), "avg_reprojection_error": float(rms)})
    log.info("calibrated %dx%d px from %d of %d images: RMS %.3f px", w, h, len(used), len(paths), rms)
    return CalibrationResult(lens, float(rms), len(paths), tuple(used), Path(out))
