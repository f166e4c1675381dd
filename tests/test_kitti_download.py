"""taco_mav/datasets/kitti_download.py without network: URLs, target names, unpacking a zip in KITTI's layout, and
its command line (tools/download_kitti.py) printing the URLs of a dry run."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from taco_mav.datasets import kitti_download as dk
from taco_mav.datasets.kitti import load_drive
from taco_mav.errors import DataError, UsageError

TOOL = Path(__file__).resolve().parents[1] / "tools" / "download_kitti.py"
UNREACHABLE = "http://127.0.0.1:9/none"  # discard port: any attempt to fetch fails at once


OXTS_LINE = ("49.0495 8.3966 113.0 0.03 0.02 1.74 5.37 -0.90 5.45 0.02 -0.06 -0.38 0.26 9.80 -0.17 -0.04 9.81 "
             "0.026 -0.004 0.019 0.026 -0.005 0.018 0.068 0.017 4 9 5 5 6\n")


def make_drive_zip(path: Path, drive: str, n: int = 3, with_oxts: bool = True) -> Path:
    """A small zip laid out like KITTI's <drive>_sync.zip (oxts, image_02, velodyne_points)."""
    date = drive[:10]
    base = f"{date}/{drive}_sync"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr(f"{base}/", "")
        if with_oxts:
            zf.writestr(f"{base}/oxts/timestamps.txt",
                        "".join(f"2011-09-30 11:54:39.{i}00000000\n" for i in range(n)))
            zf.writestr(f"{base}/oxts/dataformat.txt", "lat: ...\n")
            for i in range(n):
                zf.writestr(f"{base}/oxts/data/{i:010d}.txt", OXTS_LINE)
        zf.writestr(f"{base}/image_02/timestamps.txt",
                    "".join(f"2011-09-30 11:54:39.{i}00000000\n" for i in range(n)))
        png = cv2.imencode(".png", np.zeros((4, 6, 3), np.uint8))[1].tobytes()
        for i in range(n):
            zf.writestr(f"{base}/image_02/data/{i:010d}.png", png)
        zf.writestr(f"{base}/velodyne_points/data/0000000000.bin", b"\0" * 64)
    return path


def test_urls() -> None:
    assert dk.drive_url("2011_09_30_drive_0018") == (
        "https://s3.eu-central-1.amazonaws.com/avg-kitti/raw_data/2011_09_30_drive_0018/2011_09_30_drive_0018_sync.zip")
    assert dk.calib_url("2011_09_26") == "https://s3.eu-central-1.amazonaws.com/avg-kitti/raw_data/2011_09_26_calib.zip"
    assert dk.drive_url("2011_09_26_drive_0005", "http://mirror/raw") == \
        "http://mirror/raw/2011_09_26_drive_0005/2011_09_26_drive_0005_sync.zip"


def test_resolve_targets() -> None:
    assert dk.resolve_targets(["05", "5", "2011_09_26_drive_0005_sync"]) == ["2011_09_30_drive_0018",
                                                                           "2011_09_26_drive_0005"]
    assert dk.resolve_targets(["07-09,4"]) == ["2011_09_30_drive_0027", "2011_09_30_drive_0028",
                                               "2011_09_30_drive_0033", "2011_09_30_drive_0016"]
    assert len(dk.resolve_targets(["00-10"])) == 11
    with pytest.raises(UsageError, match="unknown KITTI odometry sequence '12'"):
        dk.resolve_targets(["12"])
    with pytest.raises(UsageError, match="'kitti': neither an odometry sequence id"):
        dk.resolve_targets(["kitti"])


def test_dry_run_prints_urls_and_fetches_nothing(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, str(TOOL), "05", "03", "--root", str(tmp_path), "--dry-run"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == [dk.calib_url("2011_09_30"), dk.calib_url("2011_09_26"),
                                  dk.drive_url("2011_09_30_drive_0018"), dk.drive_url("2011_09_26_drive_0067")]
    assert not any(tmp_path.iterdir())
    run = subprocess.run([sys.executable, str(TOOL), "99", "--root", str(tmp_path), "--dry-run"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "unknown KITTI odometry sequence '99'" in run.stderr


def test_install_keeps_selected_folders_and_loads(tmp_path: Path) -> None:
    drive = "2011_09_30_drive_0018"
    root = tmp_path / "kitti"
    zip_path = make_drive_zip(tmp_path / "d.zip", drive)
    target = dk.install_drive(zip_path, root, drive)
    assert target == root / "2011_09_30" / f"{drive}_sync"
    assert sorted(p.name for p in target.iterdir()) == ["image_02", "oxts"]  # velodyne dropped
    assert dk.verify_drive(root, drive) == [] and not (root / ".downloads" / f"{drive}.unpacking").exists()
    loaded = load_drive(target)
    assert len(loaded) == 3 and loaded.frame(2).shape == (4, 6, 3)
    # The drive now verifies, so fetching again downloads nothing (the base URL is unreachable).
    (root / "2011_09_30" / "calib_cam_to_cam.txt").write_text("S_rect_02: 1242 375\n")
    assert dk.fetch([drive], root, base_url=UNREACHABLE) == []
    assert dk.unpack(zip_path, tmp_path / "all", folders=None) == 10  # everything, velodyne included


def test_incomplete_zip_and_unsafe_members_are_refused(tmp_path: Path) -> None:
    drive = "2011_09_30_drive_0027"
    zip_path = make_drive_zip(tmp_path / "d.zip", drive, with_oxts=False)
    with pytest.raises(DataError, match="drive is incomplete: .*oxts/data missing"):
        dk.install_drive(zip_path, tmp_path / "root", drive)
    assert not (tmp_path / "root" / "2011_09_30").exists()
    evil = tmp_path / "evil.zip"
    with zipfile.ZipFile(evil, "w") as zf:
        zf.writestr("../outside.txt", "x")
    with pytest.raises(DataError, match="would be written outside"):
        dk.unpack(evil, tmp_path / "root")
    assert not (tmp_path / "outside.txt").exists()
    (tmp_path / "bad.zip").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(DataError, match="not a zip file"):
        dk.unpack(tmp_path / "bad.zip", tmp_path / "root")


def test_half_drive_is_not_overwritten(tmp_path: Path) -> None:
    half = tmp_path / "2011_09_30" / "2011_09_30_drive_0018_sync" / "oxts"
    half.mkdir(parents=True)
    (tmp_path / "2011_09_30" / "calib_cam_to_cam.txt").write_text("")
    with pytest.raises(DataError, match="exists but is incomplete .*remove it and run again"):
        dk.fetch(["2011_09_30_drive_0018"], tmp_path, base_url=UNREACHABLE)


def test_download_failure_is_a_data_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="download failed .*run again to resume"):
        dk.download(UNREACHABLE + "/x.zip", tmp_path / "x.zip", timeout_s=2.0)
    assert not (tmp_path / "x.zip").exists()
