"""Shared pytest fixtures. Real KITTI data lives beside the repository in ../shared/data (the CI layout)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import taco_mav.datasets.synthetic  # noqa: F401 - registers the `world:DIR` camera scheme (camera.open_camera)

KITTI_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_raw"
# the development tools (tools/: the SITL harnesses, the appearance-gap maker gap.py) import as top-level modules
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    """The KITTI raw root (`<root>/<date>/<date>_drive_<nnnn>_sync/oxts`); skips when it is absent."""
    if not KITTI_ROOT.is_dir():
        pytest.skip(f"KITTI raw data not found at {KITTI_ROOT} (expected ../shared/data/kitti_raw beside the repo)")
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
