"""`taco-mav calibrate` on rendered chessboards of known intrinsics and distortion: fx within 1 % and k1 within
0.02 (plumb_bob and fisheye), through the CLI entry point; clear errors for bad image folders."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from taco_mav.camera.calibration import LensCalibration, LensModel, load_calibration
from taco_mav.cli import main

BOARD, SQUARE, TEX_PX = (9, 6), 0.025, 40  # inner corners, metres per square, texture pixels per square
W, H = 640, 480


def _texture() -> np.ndarray:
    """A 9x6 (inner corners) chessboard, 10x7 squares, with one white square of margin, grey uint8."""
    cols, rows = BOARD[0] + 1, BOARD[1] + 1
    tex = np.full(((rows + 2) * TEX_PX, (cols + 2) * TEX_PX), 235, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                tex[(r + 1) * TEX_PX:(r + 2) * TEX_PX, (c + 1) * TEX_PX:(c + 2) * TEX_PX] = 20
    return tex


def render_board(lens: LensCalibration, R: np.ndarray, t: np.ndarray, tex: np.ndarray) -> np.ndarray:
    """The board (plane z = 0, first inner corner at its origin, metres) seen at pose (R, t) (board -> camera)
    through `lens`: every raw pixel's ray (inverse lens model) meets the plane; the texture is sampled there."""
    u, v = np.meshgrid(np.arange(lens.width, dtype=float), np.arange(lens.height, dtype=float))
    xy = lens.undistort(np.c_[u.ravel(), v.ravel()])
    Hinv = np.linalg.inv(np.c_[R[:, 0], R[:, 1], t])
    q = np.c_[xy, np.ones(len(xy))] @ Hinv.T
    ok = q[:, 2] > 1e-9
    X, Y = q[:, 0] / np.where(ok, q[:, 2], 1.0), q[:, 1] / np.where(ok, q[:, 2], 1.0)
    mx = np.where(ok, (2.0 + X / SQUARE) * TEX_PX - 0.5, -1e4).reshape(lens.height, lens.width).astype(np.float32)
    my = np.where(ok, (2.0 + Y / SQUARE) * TEX_PX - 0.5, -1e4).reshape(lens.height, lens.width).astype(np.float32)
    img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=90)
    return cv2.GaussianBlur(img, (0, 0), 0.6)


def _rot(rx: float, ry: float, rz: float) -> np.ndarray:
    return cv2.Rodrigues(np.array([rx, ry, rz]))[0]


def board_poses(lens: LensCalibration, n: int, seed: int,
                distance: tuple[float, float]) -> list[tuple[np.ndarray, np.ndarray]]:
    """n poses spread over the frame (corners included), tilted up to 30 deg, every corner >= 12 px inside."""
    rng = np.random.default_rng(seed)
    corners = np.zeros((BOARD[0] * BOARD[1], 3))
    corners[:, :2] = np.mgrid[0:BOARD[0], 0:BOARD[1]].T.reshape(-1, 2) * SQUARE
    centre = corners.mean(axis=0)
    targets = [(u, v) for v in (0.25, 0.5, 0.75) for u in (0.22, 0.5, 0.78)]
    targets += [(0.5, 0.5), (0.3, 0.35), (0.7, 0.65), (0.35, 0.7), (0.65, 0.3), (0.5, 0.5)]
    poses = []
    for k in range(n):
        tu, tv = targets[k % len(targets)]
        for _ in range(500):
            R = _rot(*rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.35, 0.35))
            z = rng.uniform(*distance)
            x, y = lens.undistort(np.array([[tu * lens.width, tv * lens.height]]))[0]
            t = z * np.array([x, y, 1.0]) - R @ centre
            cam = corners @ R.T + t
            uv = lens.distort(cam[:, :2] / cam[:, 2:])
            if ((uv[:, 0] > 12) & (uv[:, 0] < lens.width - 13) & (uv[:, 1] > 12) & (uv[:, 1] < lens.height - 13)).all():
                poses.append((R, t))
                break
        else:  # pragma: no cover - the pose search is deterministic
            raise AssertionError(f"no valid pose near {tu, tv}")
    return poses


def _write_boards(folder: Path, lens: LensCalibration, n: int = 15, seed: int = 1,
                  distance: tuple[float, float] = (0.32, 0.5)) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    tex = _texture()
    for i, (R, t) in enumerate(board_poses(lens, n, seed, distance)):
        cv2.imwrite(str(folder / f"board_{i:02d}.png"), render_board(lens, R, t, tex))
    return folder


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(["calibrate", *args])
    out = capsys.readouterr()
    return rc, out.out, out.err


PLUMB_BOB = LensCalibration(np.array([[520.0, 0.0, 322.3], [0.0, 520.0, 236.8], [0.0, 0.0, 1.0]]),
                            np.array([-0.28, 0.09, 0.0, 0.0, 0.0]), LensModel.PLUMB_BOB, W, H)
FISHEYE = LensCalibration(np.array([[300.0, 0.0, 318.4], [0.0, 300.0, 242.1], [0.0, 0.0, 1.0]]),
                          np.array([0.06, -0.02, 0.004, 0.0]), LensModel.FISHEYE, W, H)


@pytest.mark.parametrize("lens", [PLUMB_BOB, FISHEYE], ids=["plumb_bob", "fisheye"])
def test_calibrate_recovers_known_intrinsics(lens: LensCalibration, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    fisheye = lens.model is LensModel.FISHEYE
    images = _write_boards(tmp_path / "boards", lens, distance=(0.14, 0.22) if fisheye else (0.32, 0.5))
    out = tmp_path / "camera.yaml"
    rc, text, err = _run(["--images", str(images), "--board", "9x6", "--square", "0.025", "--out", str(out),
                          *(["--fisheye"] if fisheye else [])], capsys)
    assert rc == 0, err
    rms = float(re.search(r"RMS reprojection error ([0-9.]+) px", text).group(1))
    assert "board found in 15 of 15 images" in text and rms < 0.3, text
    got = load_calibration(out)
    assert got.model is lens.model and (got.width, got.height) == (W, H)
    fx_err = abs(got.K[0, 0] / lens.K[0, 0] - 1.0)
    k1_err = abs(got.D[0] - lens.D[0])
    print(f"{lens.model.value}: fx {got.K[0, 0]:.2f} (true {lens.K[0, 0]}, {100 * fx_err:.3f} %), k1 {got.D[0]:+.4f} "
          f"(true {lens.D[0]:+.4f}, error {k1_err:.4f}), RMS {rms:.3f} px")
    assert fx_err < 0.01 and abs(got.K[1, 1] / lens.K[1, 1] - 1.0) < 0.01
    assert k1_err < 0.02
    assert np.hypot(*(got.K[:2, 2] - lens.K[:2, 2])) < 3.0
    # the calibrated lens maps rays like the true one (within a pixel over the frame)
    xy = lens.undistort(np.array([[20.0, 20.0], [620.0, 460.0], [320.0, 240.0], [600.0, 40.0]]))
    assert np.abs(got.distort(xy) - lens.distort(xy)).max() < 1.0


def test_calibrate_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    out = str(tmp_path / "c.yaml")
    rc, _, err = _run(["--images", str(empty), "--out", out], capsys)
    assert rc == 1 and "no images" in err and str(empty) in err  # a data error: the folder holds no photos
    rc, _, err = _run(["--images", str(tmp_path / "missing"), "--out", out], capsys)
    assert rc == 2 and "--images" in err and "no such folder" in err  # a usage error: a path that is not there
    few = _write_boards(tmp_path / "few", PLUMB_BOB, n=3)
    for i in range(2):
        cv2.imwrite(str(few / f"wall_{i}.png"), np.random.default_rng(i).integers(0, 255, (H, W), np.uint8))
    rc, _, err = _run(["--images", str(few), "--out", out], capsys)
    assert rc == 1 and "found in 3 of 5 images" in err and "at least 5" in err, err
    (few / "zz_broken.png").write_bytes(b"\x89PNG not really")
    rc, _, err = _run(["--images", str(few), "--out", out], capsys)
    assert rc == 1 and "1 of 6 images unreadable: zz_broken.png" in err, err
    rc, _, err = _run(["--images", str(few), "--board", "9by6", "--out", out], capsys)
    assert rc == 2 and "--board" in err
    assert not Path(out).exists()
