"""Paint a `Scene` onto a `Canvas`: ground, parking lots, sidewalks, roads with wear and markings, junction
patterns (zebra crossings, chequerboards, yellow boxes), cast shadows, roofs and tree canopies.

Frame: local ENU metres (x east, y north). The sun stands at azimuth 150 degrees (SSE), elevation 50 degrees,
so shadows fall towards the north-north-west, 0.84 x the object's height long. Colours are RGB.
"""

from __future__ import annotations

import cv2
import numpy as np

from taco_mav.datasets.synthetic.layout import SIDEWALK_M, Scene
from taco_mav.datasets.synthetic.mosaic import Canvas, Material

__all__ = ["paint_scene", "SHADOW_DIR"]

_SUN_AZ = np.radians(150.0)
SHADOW_DIR = -np.array([np.sin(_SUN_AZ), np.cos(_SUN_AZ)]) / np.tan(np.radians(50.0))  # per metre of height
ASPHALT = (88, 88, 92)
PAVEMENT = (168, 165, 158)
WHITE = (232, 232, 228)
YELLOW = (225, 190, 40)
CAR_COLOURS = [(200, 200, 205), (30, 30, 35), (150, 20, 25), (40, 60, 120), (120, 125, 130), (230, 230, 230),
               (60, 90, 60), (180, 150, 60)]


def _frame(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arc length (N,), unit tangents (N, 2) and left normals (N, 2) of a polyline."""
    d = np.gradient(xy, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    return s, d, np.c_[-d[:, 1], d[:, 0]]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index runs where mask is True."""
    m = np.r_[False, mask, False].astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return list(zip(edges[::2], edges[1::2]))


def _ground(cv: Canvas, scene: Scene) -> None:
    """Grass/soil everywhere, yards (lighter, mixed) in built-up districts."""
    h, w = cv.shape
    dist = cv2.resize(scene.district, (w, h), interpolation=cv2.INTER_LINEAR)
    grass = np.array([78, 108, 52], np.float32)
    dry = np.array([128, 126, 82], np.float32)
    yard = np.array([138, 132, 118], np.float32)
    t = np.clip((dist - 0.25) * 3.0, 0.0, 1.0)[:, :, None]
    mix = np.clip(dist * 1.6 - 0.3, 0.0, 1.0)[:, :, None] * 0.5
    cv.img[:] = np.clip((grass * (1 - mix) + dry * mix) * (1 - t) + yard * t, 0, 255).astype(np.uint8)
    cv.mat[:] = np.where(dist > 0.45, Material.YARD, Material.GRASS).astype(np.uint8)


def lot_axes(cv: Canvas, lot) -> tuple[np.ndarray, np.ndarray, float, list[tuple[float, float]]]:
    """Paint a parking lot's asphalt; return its unit axes u (along the bays) and v (into them), ENU, its
    length along u, metres, and its bay bands (start, end) along v, metres."""
    c = lot.corners
    u = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    v = (c[3] - c[0]) / np.linalg.norm(c[3] - c[0])
    L, D = float(np.linalg.norm(c[1] - c[0])), float(np.linalg.norm(c[3] - c[0]))
    cv.poly(c, (95, 95, 98), Material.ASPHALT)
    bands = [(D - 5.0, D)] if lot.rows == 1 else [(0.0, 5.0), (D - 5.0, D)]
    return u, v, L, bands


def _lots(cv: Canvas, scene: Scene, rng: np.random.Generator) -> None:
    for lot in scene.lots:
        c = lot.corners
        u, v, L, bands = lot_axes(cv, lot)
        lines, cars = [], []
        for v0, v1 in bands:
            for k in range(int(L / 2.5) + 1):
                a = c[0] + u * (k * 2.5 + 0.2)
                lines.append(np.array([a + v * v0, a + v * v1]))
                if k < int(L / 2.5) and rng.random() < lot.occupancy:
                    cars.append((c[0] + u * (k * 2.5 + 1.45) + v * (0.5 * (v0 + v1)), rng.integers(len(CAR_COLOURS))))
        cv.line(lines, 0.15, WHITE, Material.MARKING)
        for centre, ci in cars:
            body = np.array([centre + sa * u * 0.9 + sb * v * 2.15 for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            cv.poly(body + SHADOW_DIR * 0.8, (40, 40, 42), None)
            cv.poly(body, CAR_COLOURS[ci], Material.CAR)
            glass = np.array([centre + sa * u * 0.75 + v * (0.6 + 0.5 * sb) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            cv.poly(glass, (35, 40, 50), Material.CAR)


def _roads(cv: Canvas, scene: Scene) -> None:
    for sidewalk in (True, False):
        for j, p in enumerate(scene.junctions):
            r = scene.junction_radius[j] + (SIDEWALK_M + 2.0 if sidewalk else 0.0)
            cv.circle(p, r, PAVEMENT if sidewalk else ASPHALT, Material.PAVEMENT if sidewalk else Material.ASPHALT)
        for rd in scene.roads:
            width = rd.width_m + (2 * SIDEWALK_M if sidewalk else 0.0)
            cv.line([rd.xy], width, PAVEMENT if sidewalk else ASPHALT, Material.PAVEMENT if sidewalk else Material.ASPHALT)
        if sidewalk:
            cv.line(scene.paths, 2.0, (150, 138, 115), Material.PATH)


def _wear(cv: Canvas, scene: Scene, rng: np.random.Generator) -> None:
    """Patches, cracks and manholes on the carriageways."""
    for rd in scene.roads:
        s, d, n = _frame(rd.xy)
        count = int(s[-1] / 12.0)
        idx = rng.integers(0, len(s), count)
        for i, kind in zip(idx, rng.integers(0, 3, count)):
            off = rng.uniform(-rd.width_m / 2 + 0.8, rd.width_m / 2 - 0.8)
            centre = rd.xy[i] + n[i] * off
            if kind == 0:
                a, b = rng.uniform(0.6, 3.0), rng.uniform(0.5, 2.0)
                ang = rng.uniform(0, np.pi)
                R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
                pts = centre + (np.array([[-a, -b], [a, -b], [a, b], [-a, b]]) * 0.5) @ R.T
                cv.poly(pts, (70, 70, 74) if rng.random() < 0.6 else (110, 108, 108), None)
            elif kind == 1:
                steps = rng.normal(0, 0.6, (int(rng.integers(4, 12)), 2)) + d[i] * 0.4
                cv.line([centre + np.cumsum(steps, axis=0)], 0.1, (50, 50, 52), None)
            else:
                cv.circle(centre, 0.35, (60, 60, 62), None)
                cv.circle(centre, 0.25, (105, 105, 108), None)


def _markings(cv: Canvas, scene: Scene) -> None:
    """Edge lines, dashed (streets) or double solid (avenues) centre lines, stop lines, zebra crossings."""
    edge_lines, centre_lines, blocks = [], [], []
    for rd in scene.roads:
        s, d, n = _frame(rd.xy)
        j0, j1, trim0, trim1 = -1, -1, 1.5, 1.5
        if len(scene.junctions):
            ends = [np.linalg.norm(scene.junctions - rd.xy[k], axis=1) for k in (0, -1)]
            j0, j1 = int(np.argmin(ends[0])), int(np.argmin(ends[1]))
            trim0 = scene.junction_radius[j0] + (6.5 if scene.junction_style[j0] == 1 else 1.5)
            trim1 = scene.junction_radius[j1] + (6.5 if scene.junction_style[j1] == 1 else 1.5)
        inside = (s > trim0) & (s < s[-1] - trim1)
        if inside.sum() < 3:
            continue
        for side in (-1.0, 1.0):
            edge_lines.append(rd.xy[inside] + n[inside] * side * (rd.width_m / 2.0 - 0.45))
        if rd.avenue:
            centre_lines += [rd.xy[inside] + n[inside] * 0.18, rd.xy[inside] - n[inside] * 0.18]
        else:
            dash = inside & (np.mod(s - trim0, 9.0) < 3.0)
            centre_lines += [rd.xy[a:b] for a, b in _runs(dash) if b - a >= 2]
        # stop lines across the right-hand half at both ends, zebra crossings at zebra junctions
        for k, (jj, trim) in enumerate(((j0, trim0), (j1, trim1))):
            i = int(np.searchsorted(s, trim if k == 0 else s[-1] - trim))
            i = min(max(i, 0), len(s) - 1)
            half = rd.width_m / 2.0 - 0.3
            # arriving at junction 0 means driving against the polyline: its right-hand side is +n
            right = n[i] * (1.0 if k == 0 else -1.0)
            blocks.append(np.array([rd.xy[i], rd.xy[i] + right * half]))
            if jj >= 0 and scene.junction_style[jj] == 1:
                a = scene.junction_radius[jj] + 1.5
                i0 = int(np.searchsorted(s, a if k == 0 else s[-1] - a - 4.0))
                i0 = min(max(i0, 0), len(s) - 5)
                base, t, nn = rd.xy[i0], d[i0], n[i0]
                for off in np.arange(-rd.width_m / 2 + 0.6, rd.width_m / 2 - 0.4, 1.0):
                    q = base + nn * off
                    cv.poly(np.array([q - nn * 0.25, q - nn * 0.25 + t * 4.0, q + nn * 0.25 + t * 4.0, q + nn * 0.25]),
                            WHITE, Material.MARKING)
    cv.line(edge_lines, 0.2, WHITE, Material.MARKING)
    cv.line(centre_lines, 0.2, WHITE, Material.MARKING)
    cv.line(blocks, 0.5, WHITE, Material.MARKING)


def _junction_patterns(cv: Canvas, scene: Scene) -> None:
    """Chequerboard (style 2) and yellow-box (style 3) junction squares, aligned with a road leaving it."""
    for j, p in enumerate(scene.junctions):
        style = scene.junction_style[j]
        if style not in (2, 3):
            continue
        near = [rd for rd in scene.roads if np.linalg.norm(rd.xy[0] - p) < 1.0 or np.linalg.norm(rd.xy[-1] - p) < 1.0]
        if not near:
            continue
        xy = near[0].xy if np.linalg.norm(near[0].xy[0] - p) < 1.0 else near[0].xy[::-1]
        t = (xy[min(8, len(xy) - 1)] - xy[0])
        t /= np.linalg.norm(t)
        half = scene.junction_radius[j] * 0.8
        roi = cv.roi_local(p, half * 1.5)
        if roi is None:
            continue
        rs, cs, X, Y = roi
        u = (X - p[0]) * t[0] + (Y - p[1]) * t[1]
        v = -(X - p[0]) * t[1] + (Y - p[1]) * t[0]
        inside = (np.abs(u) < half) & (np.abs(v) < half)
        if style == 2:
            dark = (np.floor(u / 1.0) + np.floor(v / 1.0)) % 2 == 0
            colours = np.where(dark[:, :, None], np.array([80, 76, 74], np.uint8), np.array([185, 178, 168], np.uint8))
            sel = inside
        else:
            hatch = (np.mod(u + v, 2.2) < 0.3) | (np.mod(u - v, 2.2) < 0.3)
            border = inside & ((np.abs(u) > half - 0.3) | (np.abs(v) > half - 0.3))
            sel = inside & (hatch | border)
            colours = np.broadcast_to(np.array(YELLOW, np.uint8), sel.shape + (3,))
        img, mat = cv.img[rs, cs], cv.mat[rs, cs]
        img[sel] = colours[sel]
        mat[sel] = Material.MARKING


def _shadows_and_objects(cv: Canvas, scene: Scene, rng: np.random.Generator) -> None:
    """Cast shadows (into the shadow mask), then roofs and canopies (which clear the mask under them)."""
    for b in scene.buildings:
        hull = cv2.convexHull(np.vstack([b.corners, b.corners + SHADOW_DIR * b.height_m]).astype(np.float32))
        cv2.fillPoly(cv.shadow, [cv.px(hull[:, 0, :])], 255, cv2.LINE_AA, shift=3)
    for x, y, r in scene.trees:
        cv.circle(np.array([x, y]) + SHADOW_DIR * 2.2 * r, r * 0.95, 255, None, target=cv.shadow)
    for b in scene.buildings:
        c = b.corners
        cv2.fillPoly(cv.shadow, [cv.px(c)], 0, cv2.LINE_8, shift=3)
        col = np.array(b.colour, np.float64)
        long_first = np.linalg.norm(c[1] - c[0]) >= np.linalg.norm(c[3] - c[0])
        if b.gable:
            a, bb, cc, dd = (c if long_first else np.roll(c, -1, axis=0))
            m0, m1 = 0.5 * (a + dd), 0.5 * (bb + cc)
            lit = np.dot(0.5 * (a + bb) - m0, -SHADOW_DIR) > 0
            cv.poly(np.array([a, bb, m1, m0]), np.clip(col * (1.12 if lit else 0.8), 0, 255), Material.ROOF)
            cv.poly(np.array([m0, m1, cc, dd]), np.clip(col * (0.8 if lit else 1.12), 0, 255), Material.ROOF)
            cv.line([np.array([m0, m1])], 0.3, np.clip(col * 0.6, 0, 255), Material.ROOF)
        else:
            cv.poly(c, col, Material.ROOF)
            ctr = c.mean(axis=0)
            cv.line([np.vstack([ctr + (c - ctr) * 0.93, ctr + (c[0] - ctr) * 0.93])], 0.35, np.clip(col * 0.7, 0, 255), Material.ROOF)
            for _ in range(int(rng.integers(0, 4))):
                q = ctr + (c[1] - c[0]) * rng.uniform(-0.3, 0.3) + (c[3] - c[0]) * rng.uniform(-0.3, 0.3)
                e1 = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0]) * rng.uniform(0.6, 2.0)
                e2 = (c[3] - c[0]) / np.linalg.norm(c[3] - c[0]) * rng.uniform(0.6, 2.0)
                unit = np.array([q - e1 - e2, q + e1 - e2, q + e1 + e2, q - e1 + e2])
                cv.poly(unit + SHADOW_DIR * 0.8, np.clip(col * 0.55, 0, 255), Material.ROOF)
                cv.poly(unit, (40, 50, 80) if rng.random() < 0.4 else (200, 200, 198), Material.ROOF)
    sun = -SHADOW_DIR / np.linalg.norm(SHADOW_DIR)
    for (x, y, r), tone in zip(scene.trees, rng.uniform(0.8, 1.2, len(scene.trees))):
        p = np.array([x, y])
        cv.circle(p, r, 0, None, target=cv.shadow)
        cv.circle(p, r, np.array([38, 62, 30]) * tone, Material.TREE)
        cv.circle(p + sun * r * 0.3, r * 0.65, np.array([62, 96, 44]) * tone, Material.TREE)
        cv.circle(p + sun * r * 0.45, r * 0.3, np.array([90, 124, 60]) * tone, Material.TREE)


def paint_scene(cv: Canvas, scene: Scene, rng: np.random.Generator) -> None:
    """Draw every layer of `scene` onto `cv` in painter's order."""
    _ground(cv, scene)
    _lots(cv, scene, rng)
    _roads(cv, scene)
    _wear(cv, scene, rng)
    _junction_patterns(cv, scene)
    _markings(cv, scene)
    _shadows_and_objects(cv, scene, rng)
