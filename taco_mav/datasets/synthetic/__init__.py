"""Synthetic worlds: a procedural satellite mosaic and a drive through it, written in KITTI raw layout
(`build_world`), and read back as a `Drive` whose frames are rendered on demand (`load_world`).

Importing this package registers the `world:DIR` camera scheme with `taco_mav.camera.sources.open_camera`
(`world_camera.WorldSource`, rendering the world at the simulator's true pose). The import is light: the world
builder and the renderers load when first used, so a daemon that only needs the camera scheme starts quickly."""

from __future__ import annotations

from taco_mav.datasets.synthetic.world_camera import WorldSource, register_world_camera

__all__ = ["build_world", "load_world", "SyntheticDrive", "WorldSource", "register_world_camera"]

register_world_camera()


def __getattr__(name: str):
    if name == "build_world":
        from taco_mav.datasets.synthetic.world import build_world

        return build_world
    if name in ("load_world", "SyntheticDrive"):
        from taco_mav.datasets.synthetic import drive

        return getattr(drive, name)
    raise AttributeError(name)
