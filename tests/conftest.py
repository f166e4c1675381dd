"""Shared pytest fixtures. Real KITTI data: the folder $TACO_KITTI_ROOT names (e.g. one filled by
`python tools/download_kitti.py 04 05 07 09 --root data/kitti_raw`), else ../shared/data/kitti_raw beside the
repository (the CI layout): `taco_mav.datasets.kitti.default_kitti_root`."""

from __future__ import annotations

from pathlib import Path

import pytest

import taco_mav.datasets.synthetic  # noqa: F401 - registers the `world:DIR` camera scheme (camera.open_camera)
from taco_mav.datasets.kitti import default_kitti_root

_root = default_kitti_root()
KITTI_ROOT = None if _root is None else _root.resolve()  # absolute: a test may change the working directory


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    """The KITTI raw root (`<root>/<date>/<date>_drive_<nnnn>_sync/oxts`); skips when it is absent."""
    if KITTI_ROOT is None:
        pytest.skip("KITTI raw data not found: set TACO_KITTI_ROOT to a root filled by tools/download_kitti.py "
                    "(README.md), or have ../shared/data/kitti_raw beside the repo")
    return KITTI_ROOT


@pytest.fixture(autouse=True)
def _cli_logging_left_behind():
    """Tests that call the CLI in-process install its stderr handler on the root logger (as `main` does for a
    user); remove it afterwards so later tests' log records stay in pytest's capture."""
    import logging

    from taco_mav.cli_support import TqdmHandler

    root = logging.getLogger()
    level = root.level
    yield
    for handler in [h for h in root.handlers if isinstance(h, TqdmHandler)]:
        root.removeHandler(handler)
    root.setLevel(level)
