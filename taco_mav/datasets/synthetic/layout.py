"""Scene layout around a road network: building footprints, trees, parking lots and park paths.

Frame: local ENU metres (x east, y north) relative to the world centre. Placement runs on a 1 m occupancy grid
of the scene extent: roads and sidewalks are blocked first; a low-frequency district field picks, per place,
built-up blocks, parking or parkland; objects face the nearest road (from the gradient of the distance to the
roads) and are accepted only where their footprint is free. Everything is drawn from the caller's generator.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from taco_mav.datasets.synthetic.roads import Road

log = logging.getLogger(__name__)

__all__ = ["Building", "ParkingLot", "Scene", "layout_scene", "coarse_noise"]

SIDEWALK_M = 2.5  # sidewalk width each side of the carriageway, metres
KEEP_CLEAR_M = 4.0  # half-width of the corridor a `keep_clear` path gets: no building, lot or tree centre in it
ROOF_COLOURS = np.array([
    (150, 75, 60), (170, 95, 70), (120, 60, 50), (110, 110, 115), (80, 82, 88), (150, 150, 150),
    (200, 198, 190), (95, 120, 110), (130, 115, 95), (60, 60, 65), (185, 170, 150), (140, 90, 80),
], dtype=np.float64)


@dataclass(frozen=True)
class Building:
    """A rectangular building. corners: (4, 2) local ENU metres (counter-clockwise); height_m: metres;
    colour: roof RGB; gable: a ridge along the long axis (two roof halves shaded differently)."""

    corners: np.ndarray
    height_m: float
    colour: tuple[int, int, int]
    gable: bool


@dataclass(frozen=True)
class ParkingLot:
    """A parking lot. corners: (4, 2) local ENU metres, corners[0]->corners[1] along the road side;
    rows: bay rows (1 or 2); occupancy: share of bays holding a car."""

    corners: np.ndarray
    rows: int
    occupancy: float


@dataclass
class Scene:
    """Everything the mosaic painter draws. extent: (xmin, ymin, xmax, ymax) local metres. junctions: (K, 2)
    local metres with junction_style (K,) (0 plain, 1 zebra, 2 chequerboard, 3 yellow box) and
    junction_radius (K,) metres. trees: (T, 3) x, y, canopy radius metres. paths: footpath polylines.
    district: (H, W) float32 field on the 1 m grid (0 park .. 1 built-up) with its origin at (xmin, ymax)."""

    extent: tuple[float, float, float, float]
    roads: list[Road]
    junctions: np.ndarray
    junction_style: np.ndarray
    junction_radius: np.ndarray
    buildings: list[Building] = field(default_factory=list)
    lots: list[ParkingLot] = field(default_factory=list)
    trees: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    paths: list[np.ndarray] = field(default_factory=list)
    district: np.ndarray = field(default_factory=lambda: np.zeros((1, 1), np.float32))


def coarse_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: float) -> np.ndarray:
    """Smooth noise in [0, 1], shape (H, W) float32, with features about `cell_px` pixels across."""
    h, w = shape
    g = rng.random((int(h / cell_px) + 3, int(w / cell_px) + 3)).astype(np.float32)
    M = np.array([[1.0 / cell_px, 0.0, 1.0], [0.0, 1.0 / cell_px, 1.0]])
    return cv2.warpAffine(g, M, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)


class _OccupancyGrid:
    """The 1 m occupancy grid: local (x, y) metres <-> (col, row) with row 0 at ymax."""

    def __init__(self, extent: tuple[float, float, float, float]) -> None:
        self.x0, self.y0, x1, y1 = extent
        self.y1 = y1
        self.w, self.h = int(np.ceil(x1 - self.x0)), int(np.ceil(y1 - self.y0))
        self.occ = np.zeros((self.h, self.w), np.uint8)

    def px(self, xy: np.ndarray) -> np.ndarray:
        return np.c_[xy[..., 0] - self.x0, self.y1 - xy[..., 1]]

    def free(self, poly: np.ndarray) -> bool:
        p = self.px(poly)
        c0, r0 = np.floor(p.min(axis=0)).astype(int) - 1
        c1, r1 = np.ceil(p.max(axis=0)).astype(int) + 1
        if c0 < 0 or r0 < 0 or c1 > self.w or r1 > self.h:
            return False
        roi = self.occ[r0:r1, c0:c1]
        m = np.zeros_like(roi)
        cv2.fillConvexPoly(m, np.round((p - (c0, r0)) * 4).astype(np.int32), 1, shift=2)
        return not np.any(roi & m)

    def mark(self, poly: np.ndarray) -> None:
        cv2.fillConvexPoly(self.occ, np.round(self.px(poly) * 4).astype(np.int32), 1, shift=2)


def _rect(centre: np.ndarray, axis: np.ndarray, along: float, across: float) -> np.ndarray:
    """Corners (4, 2) of a rectangle: `along` metres on unit `axis`, `across` metres perpendicular."""
    perp = np.array([-axis[1], axis[0]])
    a, b = axis * along / 2.0, perp * across / 2.0
    return np.array([centre - a - b, centre + a - b, centre + a + b, centre - a + b])


def layout_scene(rng: np.random.Generator, extent: tuple[float, float, float, float], roads: list[Road],
                 junctions: np.ndarray, junction_style: np.ndarray, keep_clear: Sequence[np.ndarray] = ()) -> Scene:
    """Place buildings, parking lots, trees and park paths around `roads` within `extent` (local metres).
    keep_clear: polylines (N, 2) local metres another vehicle drives (a SITL mission off the streets): nothing
    that stands up is placed within KEEP_CLEAR_M of them."""
    grid = _OccupancyGrid(extent)
    road_mask = np.zeros_like(grid.occ)
    for r in roads:
        pts = np.round(grid.px(r.xy) * 4).astype(np.int32)
        cv2.polylines(road_mask, [pts], False, 1, thickness=int(np.ceil(r.width_m + 2 * SIDEWALK_M)), shift=2)
    jr = np.zeros(len(junctions))
    for k, p in enumerate(junctions):
        widths = [r.width_m for r in roads if min(np.linalg.norm(r.xy[[0, -1]] - p, axis=1)) < 1.0]
        jr[k] = (max(widths) if widths else 7.0) / 2.0 + 1.0
        c = grid.px(p[None])[0]
        cv2.circle(road_mask, tuple(np.round(c * 4).astype(int)), int(4 * (jr[k] + SIDEWALK_M)), 1, -1, shift=2)
    dist = cv2.distanceTransform((1 - road_mask).astype(np.uint8), cv2.DIST_L2, 5)
    smooth = cv2.GaussianBlur(dist, (0, 0), 2.0)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = -cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)  # rows grow southwards
    grid.occ[:] = cv2.dilate(road_mask, np.ones((3, 3), np.uint8))
    for line in keep_clear:
        pts = np.round(grid.px(np.asarray(line, np.float64)) * 4).astype(np.int32)
        cv2.polylines(grid.occ, [pts], False, 1, thickness=int(np.ceil(2 * KEEP_CLEAR_M)), shift=2)
    district = coarse_noise(rng, grid.occ.shape, 140.0)
    scene = Scene(extent=extent, roads=roads, junctions=junctions, junction_style=junction_style,
                  junction_radius=jr, district=district)

    def at(xy: np.ndarray) -> tuple[int, int]:
        c = grid.px(xy[None])[0]
        return int(np.clip(c[1], 0, grid.h - 1)), int(np.clip(c[0], 0, grid.w - 1))

    # Parking lots next to roads in the parking band of the district field.
    area = grid.w * grid.h
    for _ in range(int(area / 900)):
        p = rng.uniform((grid.x0, grid.y0), (grid.x0 + grid.w, grid.y1))
        r, c = at(p)
        if not (0.30 <= district[r, c] < 0.42) or not (3.0 < dist[r, c] < 10.0):
            continue
        n = np.array([gx[r, c], gy[r, c]])
        if np.linalg.norm(n) < 1e-3:
            continue
        n /= np.linalg.norm(n)
        rows = int(rng.integers(1, 3))
        depth = 5.0 * rows + 6.0
        along = float(rng.uniform(25.0, 60.0))
        centre = p + n * (depth / 2.0 - dist[r, c] + 3.5)
        corners = _rect(centre, np.array([n[1], -n[0]]), along, depth)
        if grid.free(corners):
            grid.mark(_rect(centre, np.array([n[1], -n[0]]), along + 2, depth + 2))
            scene.lots.append(ParkingLot(corners=corners, rows=rows, occupancy=float(rng.uniform(0.3, 0.9))))

    # Buildings in the built-up band, fronts 3-10 m behind the sidewalk, facing the road.
    for _ in range(int(area / 60)):
        p = rng.uniform((grid.x0, grid.y0), (grid.x0 + grid.w, grid.y1))
        r, c = at(p)
        if district[r, c] < 0.42 or dist[r, c] < 5.0:
            continue
        n = np.array([gx[r, c], gy[r, c]])
        if dist[r, c] < 40.0 and np.linalg.norm(n) > 1e-3:
            n /= np.linalg.norm(n)
        else:
            ang = rng.uniform(0, np.pi)
            n = np.array([np.cos(ang), np.sin(ang)])
        depth, width = float(rng.uniform(8.0, 20.0)), float(rng.uniform(8.0, 32.0))
        corners = _rect(p, n, depth, width)
        if grid.free(_rect(p, n, depth + 3.0, width + 3.0)):
            grid.mark(_rect(p, n, depth + 2.0, width + 2.0))
            colour = ROOF_COLOURS[rng.integers(len(ROOF_COLOURS))] * rng.uniform(0.85, 1.15)
            scene.buildings.append(Building(corners=corners, height_m=float(rng.uniform(5.0, 22.0)),
                                            colour=tuple(int(v) for v in np.clip(colour, 0, 255)),
                                            gable=bool(rng.random() < 0.55)))

    # Park footpaths: smooth random walks in the parkland band.
    for _ in range(int(area / 40000) + 1):
        p = rng.uniform((grid.x0, grid.y0), (grid.x0 + grid.w, grid.y1))
        if district[at(p)] >= 0.3:
            continue
        ang, pts = rng.uniform(0, 2 * np.pi), [p]
        for _ in range(60):
            ang += rng.normal(0, 0.12)
            pts.append(pts[-1] + 2.0 * np.array([np.cos(ang), np.sin(ang)]))
        scene.paths.append(np.array(pts))

    # Trees: street rows on the sidewalk edge (a repetitive pattern), parkland clusters, yard trees.
    trees: list[tuple[float, float, float]] = []
    for rd in roads:
        if rng.random() < 0.45:
            continue
        step, off = float(rng.uniform(9.0, 13.0)), rd.width_m / 2.0 + SIDEWALK_M + 1.5
        d = np.gradient(rd.xy, axis=0)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        for i in range(int(step), len(rd.xy) - int(step), int(step)):
            for side in (-1.0, 1.0):
                q = rd.xy[i] + side * off * np.array([-d[i, 1], d[i, 0]])
                if dist[at(q)] > 0.5 and grid.occ[at(q)] == 0:
                    trees.append((q[0], q[1], float(rng.uniform(2.5, 3.5))))
    for _ in range(int(area / 45)):
        p = rng.uniform((grid.x0, grid.y0), (grid.x0 + grid.w, grid.y1))
        r, c = at(p)
        prob = 0.6 if district[r, c] < 0.3 else 0.08
        if dist[r, c] > 3.0 and grid.occ[r, c] == 0 and rng.random() < prob:
            rad = float(rng.uniform(2.0, 5.5))
            trees.append((p[0], p[1], rad))
            cv2.circle(grid.occ, (c, r), int(rad * 0.6), 1, -1)
    scene.trees = np.array(trees, dtype=np.float64).reshape(-1, 3)
    log.debug("scene: %d buildings, %d lots, %d trees, %d paths", len(scene.buildings), len(scene.lots),
              len(scene.trees), len(scene.paths))
    return scene
