"""What every synthetic world builder shares (the grid world in `world.py`, the along-a-drive world in
`along.py`): the generator version, the mosaic resolution, the mosaic extent around a route, and painting the
scene into `mosaic.tif`. Both builders import this module; neither imports the other's internals, so there is
no import cycle between them.

Frames: local ENU metres relative to the world centre (`centre_utm`, UTM metres of its zone).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from taco_mav.datasets.synthetic.layout import Scene
from taco_mav.datasets.synthetic.mosaic import Canvas, write_geotiff
from taco_mav.datasets.synthetic.paint import paint_scene

log = logging.getLogger(__name__)

__all__ = ["GENERATOR_VERSION", "MARGIN_M", "M_PER_PX", "paint_and_write", "world_extent"]

GENERATOR_VERSION = "taco_mav.synthetic/1"
M_PER_PX = 0.2  # mosaic resolution, m/px
MARGIN_M = 150.0  # mosaic margin around the route's bounding box, m


def world_extent(xy: np.ndarray, centre_utm: tuple[float, float]) -> tuple[float, float, float, float, int, int]:
    """Local extent (x0, y0, x1, y1) of the route (N, 2) bbox plus the margin, snapped to whole UTM metres, and
    its size in pixels (width, height)."""
    e0 = math.floor(centre_utm[0] + xy[:, 0].min() - MARGIN_M)
    e1 = math.ceil(centre_utm[0] + xy[:, 0].max() + MARGIN_M)
    n0 = math.floor(centre_utm[1] + xy[:, 1].min() - MARGIN_M)
    n1 = math.ceil(centre_utm[1] + xy[:, 1].max() + MARGIN_M)
    w, h = int(round((e1 - e0) / M_PER_PX)), int(round((n1 - n0) / M_PER_PX))
    return e0 - centre_utm[0], n0 - centre_utm[1], e1 - centre_utm[0], n1 - centre_utm[1], w, h


def paint_and_write(scene: Scene, out: Path, x0: float, y1: float, w: int, h: int, epsg: int,
                    centre_utm: tuple[float, float], seed: int, rng: np.random.Generator, progress: bool) -> str:
    """Paint the scene into a w x h px canvas whose top-left corner is local (x0, y1) and write
    `out/mosaic.tif`; returns the file name."""
    canvas = Canvas.blank(x0, y1, w, h, M_PER_PX)
    paint_scene(canvas, scene, rng)
    write_geotiff(canvas, out / "mosaic.tif", epsg, centre_utm, seed, progress=progress)
    return "mosaic.tif"
