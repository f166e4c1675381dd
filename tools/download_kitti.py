#!/usr/bin/env python3
"""Download KITTI raw "sync" drives (and their day's calibration) into KITTI's own layout.

    python tools/download_kitti.py 05 07 2011_09_26_drive_0005 --root data/kitti_raw
    python tools/download_kitti.py 00-10 --root data/kitti_raw --dry-run      # print the URLs only

Targets are odometry sequence ids ("05", ranges like "00-10") or raw drive names ("2011_09_30_drive_0018",
with or without "_sync"). Each drive zip is fetched to `<root>/.downloads/` (resumed with an HTTP Range
request when a partial `.part` file is there), unpacked to `<root>/<date>/<date>_drive_<nnnn>_sync/` keeping
only `--folders` (default: oxts and image_02, what taco_mav reads), verified (oxts/data and timestamps.txt,
equal counts) and deleted unless `--keep-zips`. A drive that already verifies is skipped, so an interrupted
run can simply be started again. KITTI raw data is CC BY-NC-SA 3.0 (Geiger et al., IJRR 2013); register at
https://www.cvlibs.net/datasets/kitti/ and accept the licence before downloading. A command line over
`taco_mav.datasets.kitti_download`.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import Sequence

from taco_mav.datasets.kitti_download import BASE_URL, DEFAULT_FOLDERS, fetch, resolve_targets
from taco_mav.errors import TacoError

log = logging.getLogger("download_kitti")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("targets", nargs="+", help="odometry ids (05, 00-10) or drive names (2011_09_30_drive_0018)")
    parser.add_argument("--root", type=Path, required=True, help="KITTI raw root to fill")
    parser.add_argument("--folders", default=",".join(DEFAULT_FOLDERS),
                        help="drive sub-folders to keep, comma-separated, or 'all' (default: %(default)s)")
    parser.add_argument("--keep-zips", action="store_true", help="keep the downloaded zips in ROOT/.downloads")
    parser.add_argument("--dry-run", action="store_true", help="print the URLs that would be fetched and exit")
    parser.add_argument("--base-url", default=BASE_URL, help="mirror of KITTI's raw_data folder")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    folders = None if args.folders.strip() == "all" else tuple(f.strip() for f in args.folders.split(",") if f.strip())
    try:
        urls = fetch(resolve_targets(args.targets), args.root, folders=folders, keep_zips=args.keep_zips,
                     dry_run=args.dry_run, base_url=args.base_url.rstrip("/"))
    except TacoError as exc:
        log.error("error: %s", exc)
        return exc.exit_code
    except KeyboardInterrupt:
        log.error("interrupted: run the same command again to resume")
        return 130
    if args.dry_run:
        sys.stdout.write("".join(u + "\n" for u in urls))
    return 0


if __name__ == "__main__":
    sys.exit(main())
