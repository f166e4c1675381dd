"""Download KITTI raw "sync" drives (and their day's calibration) into KITTI's own layout
(`tools/download_kitti.py` is its command line).

Targets are odometry sequence ids ("05", ranges like "00-10") or raw drive names ("2011_09_30_drive_0018",
with or without "_sync"): `resolve_targets`. `fetch` downloads each drive zip to `<root>/.downloads/` (resumed
with an HTTP Range request when a partial `.part` file is there), unpacks it to
`<root>/<date>/<date>_drive_<nnnn>_sync/` keeping only `folders` (default: oxts and image_02, what taco_mav
reads), verifies it (oxts/data and timestamps.txt, equal counts) and deletes the zip unless `keep_zips`. A drive
that already verifies is skipped, so an interrupted run can simply be started again. Errors are `DataError`
(a failed download, a bad zip, an incomplete drive) and `UsageError` (a target that is neither an id nor a
drive name). KITTI raw data is CC BY-NC-SA 3.0 (Geiger et al., IJRR 2013); register at
https://www.cvlibs.net/datasets/kitti/ and accept the licence before downloading.
"""

from __future__ import annotations

import logging
import re
import shutil
import urllib.error
import urllib.request
import zipfile
from pathlib import Path, PurePosixPath
from typing import Sequence

from taco_mav.datasets.kitti import ODOMETRY_SEQUENCES
from taco_mav.errors import DataError, UsageError

log = logging.getLogger(__name__)

__all__ = ["BASE_URL", "DEFAULT_FOLDERS", "calib_url", "download", "drive_dir", "drive_url", "fetch", "install_drive",
           "resolve_targets", "unpack", "verify_drive"]

BASE_URL = "https://s3.eu-central-1.amazonaws.com/avg-kitti/raw_data"
DEFAULT_FOLDERS = ("oxts", "image_02")
_DRIVE_RE = re.compile(r"^(\d{4}_\d{2}_\d{2})_drive_(\d{4})(?:_sync)?$")
_CHUNK = 1 << 20


def drive_url(drive: str, base_url: str = BASE_URL) -> str:
    """URL of a raw drive's synced+rectified zip, e.g. .../2011_09_30_drive_0018/2011_09_30_drive_0018_sync.zip."""
    return f"{base_url}/{drive}/{drive}_sync.zip"


def calib_url(date: str, base_url: str = BASE_URL) -> str:
    """URL of a recording day's calibration zip, e.g. .../2011_09_30_calib.zip."""
    return f"{base_url}/{date}_calib.zip"


def resolve_targets(targets: Sequence[str]) -> list[str]:
    """Drive names ("2011_09_30_drive_0018") for sequence ids, id ranges ("00-10") and drive names, in order,
    without repeats. Raises UsageError (exit 2) for anything else."""
    drives: list[str] = []
    for raw in targets:
        for item in filter(None, (s.strip() for s in raw.split(","))):
            names: list[str]
            match = _DRIVE_RE.match(item)
            if match:
                names = [f"{match.group(1)}_drive_{match.group(2)}"]
            elif re.fullmatch(r"\d{1,2}-\d{1,2}", item):
                lo, hi = (int(x) for x in item.split("-"))
                names = [_sequence_drive(f"{i:02d}") for i in range(lo, hi + 1)]
            elif item.isdigit():
                names = [_sequence_drive(item.zfill(2))]
            else:
                raise UsageError(f"{item!r}: neither an odometry sequence id (00-10) nor a drive name "
                                "like 2011_09_30_drive_0018")
            drives.extend(n for n in names if n not in drives)
    return drives


def _sequence_drive(key: str) -> str:
    if key not in ODOMETRY_SEQUENCES:
        raise UsageError(f"unknown KITTI odometry sequence {key!r} (known: {', '.join(ODOMETRY_SEQUENCES)})")
    return ODOMETRY_SEQUENCES[key].drive_name


def drive_dir(root: Path, drive: str) -> Path:
    """Where a drive lives in KITTI's layout: <root>/<date>/<drive>_sync."""
    return root / drive[:10] / f"{drive}_sync"


def verify_drive(root: Path, drive: str) -> list[str]:
    """Problems with an unpacked drive (empty list when oxts/data and oxts/timestamps.txt are consistent)."""
    oxts = drive_dir(root, drive) / "oxts"
    if not (oxts / "data").is_dir():
        return [f"{oxts / 'data'} missing"]
    if not (oxts / "timestamps.txt").is_file():
        return [f"{oxts / 'timestamps.txt'} missing"]
    n_files = sum(1 for p in (oxts / "data").glob("*.txt"))
    n_lines = sum(1 for line in (oxts / "timestamps.txt").read_text().splitlines() if line.strip())
    problems = [] if n_files else [f"{oxts / 'data'} is empty"]
    if n_files != n_lines:
        problems.append(f"{oxts}: {n_files} OXTS files but {n_lines} timestamps")
    return problems


def unpack(zip_path: Path, root: Path, folders: Sequence[str] | None = None) -> int:
    """Extract a KITTI zip into root, keeping only the drive sub-folders in `folders` (None: everything;
    files outside a drive folder, such as calibration, are always kept). Refuses members that would land
    outside root. Returns the number of files written."""
    root = root.resolve()
    written = 0
    try:
        archive = zipfile.ZipFile(zip_path)
    except zipfile.BadZipFile:
        raise DataError(f"{zip_path}: not a zip file (a partial or failed download? delete it and retry)") from None
    with archive:
        for info in archive.infolist():
            member = PurePosixPath(info.filename)
            if member.is_absolute() or ".." in member.parts:
                raise DataError(f"{zip_path}: member {info.filename!r} would be written outside {root}")
            if info.is_dir():
                continue
            parts = member.parts
            in_drive = len(parts) >= 3 and parts[1].endswith("_sync")
            if folders is not None and in_drive and parts[2] not in folders:
                continue
            target = root.joinpath(*parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            with archive.open(info) as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst, _CHUNK)
            written += 1
    return written


def install_drive(zip_path: Path, root: Path, drive: str, folders: Sequence[str] | None = DEFAULT_FOLDERS) -> Path:
    """Unpack a drive zip into a staging folder beside the downloads, verify it, then move the drive folder
    into KITTI's layout under root in one rename, so an interrupted run never leaves a half drive behind."""
    staging = root / ".downloads" / f"{drive}.unpacking"
    if staging.exists():
        shutil.rmtree(staging)
    n = unpack(zip_path, staging, folders)
    problems = verify_drive(staging, drive)
    if problems:
        shutil.rmtree(staging)
        raise DataError(f"{zip_path}: unpacked {n} files but the drive is incomplete: {'; '.join(problems)}")
    target = drive_dir(root, drive)
    target.parent.mkdir(parents=True, exist_ok=True)
    drive_dir(staging, drive).rename(target)
    shutil.rmtree(staging)
    log.info("%s: %d files unpacked into %s", drive, n, target)
    return target


def download(url: str, dest: Path, timeout_s: float = 60.0) -> Path:
    """Fetch url to dest, resuming `dest.part` with a Range request; the file appears only when complete."""
    if dest.is_file():
        return dest
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    have = part.stat().st_size if part.exists() else 0
    request = urllib.request.Request(url, headers={"Range": f"bytes={have}-"} if have else {})
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as response:
            resumed = have and response.status == 206
            if have and not resumed:
                log.info("%s: server ignored the range request, starting again", url)
            with open(part, "ab" if resumed else "wb") as fh:
                shutil.copyfileobj(response, fh, _CHUNK)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # the partial file is already complete
            part.rename(dest)
            return dest
        raise DataError(f"{url}: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, TimeoutError, OSError) as exc:
        raise DataError(f"{url}: download failed ({exc}); run again to resume") from None
    part.rename(dest)
    return dest


def fetch(drives: Sequence[str], root: Path, *, folders: Sequence[str] | None = DEFAULT_FOLDERS,
          keep_zips: bool = False, dry_run: bool = False, base_url: str = BASE_URL) -> list[str]:
    """Download, unpack and verify each drive (and its day's calibration) under root. Returns the URLs that
    were (or, with dry_run, would be) fetched; drives that already verify are skipped."""
    urls: list[str] = []
    cache = root / ".downloads"
    for date in dict.fromkeys(d[:10] for d in drives):
        if not (root / date / "calib_cam_to_cam.txt").is_file():
            urls.append(calib_url(date, base_url))
            if not dry_run:
                zip_path = download(urls[-1], cache / f"{date}_calib.zip")
                unpack(zip_path, root)
                if not keep_zips:
                    zip_path.unlink()
    for drive in drives:
        target = drive_dir(root, drive)
        if not verify_drive(root, drive):
            log.info("%s: already present, skipped", drive)
            continue
        if target.exists():
            raise DataError(f"{target} exists but is incomplete ({'; '.join(verify_drive(root, drive))}); "
                            "remove it and run again")
        urls.append(drive_url(drive, base_url))
        if dry_run:
            continue
        log.info("%s: downloading %s", drive, urls[-1])
        zip_path = download(urls[-1], cache / f"{drive}_sync.zip")
        install_drive(zip_path, root, drive, folders)
        if not keep_zips:
            zip_path.unlink()
    return urls
