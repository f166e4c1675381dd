"""Synthetic worlds: a procedural satellite mosaic and a drive through it, written in KITTI raw layout
(`build_world`), and read back as a `Drive` whose frames are rendered on demand (`load_world`)."""

from __future__ import annotations

from taco_mav.datasets.synthetic.world import build_world

__all__ = ["build_world", "load_world", "SyntheticDrive"]


def __getattr__(name: str):
    if name in ("load_world", "SyntheticDrive"):
        from taco_mav.datasets.synthetic import drive

        return getattr(drive, name)
    raise AttributeError(name)
