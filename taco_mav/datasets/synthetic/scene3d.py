"""The 3-D scene of a synthetic world: triangle meshes of buildings, trees, poles and cars around a `Scene` layout.

Frame: local ENU metres relative to the world centre (x east, y north, z up, ground at z = 0). Meshes are flat
triangle lists (no index buffer, one normal per face) with per-vertex attributes:
  pos (N, 3) float32 metres; nrm (N, 3) float32 unit normals; col (N, 3) float32 linear RGB in [0, 1];
  mat (N,) float32 material id (`Mat`); uv (N, 2) float32 surface metres (facades: along the wall, height).
Objects:
- buildings: the layout's footprints extruded to their height; flat roofs (with rooftop units) or gables
  (ridge along the long side, rise 0.3 x the short side); facades in one of a few plaster/brick colours.
- trees: a trunk and a jittered ellipsoidal crown (icosphere), crown bottom 2.2-3 m, so street trees overhang
  the kerb and hide the road edge from above.
- poles: street lamps (7-8 m, an arm over the road) along a share of the roads, sign posts at junctions.
- parked cars: the layout's parking bays and kerb-side parking on avenues; drawn per EPOCH (the camera's day
  and the aerial photo's day): a bay keeps its car with probability `STAY`, otherwise it is drawn again.
- moving cars: drive along single roads in the right-hand lane at constant speed, wrapping at the road's end;
  positions are a function of time (`moving_cars_at`). Cars that would come within 3 m of the ego vehicle at
  any camera frame time are dropped, and static objects keep clear of the ego path.
Everything is drawn from the caller's generator.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from taco_mav.datasets.synthetic.layout import SIDEWALK_M, Scene

log = logging.getLogger(__name__)

__all__ = ["Mat", "Mesh", "Scene3D", "MovingCars", "build_scene3d", "moving_cars_at", "car_mesh"]

STAY = 0.55  # probability that a parked car is still there on the other epoch's day
CAR_L, CAR_W = 4.3, 1.8
FACADES = np.array([(0.80, 0.76, 0.68), (0.72, 0.66, 0.58), (0.62, 0.36, 0.28), (0.85, 0.83, 0.78),
                    (0.55, 0.55, 0.57), (0.78, 0.70, 0.52), (0.68, 0.74, 0.76)], np.float32)
CAR_RGB = np.array([(0.78, 0.78, 0.80), (0.10, 0.10, 0.12), (0.55, 0.06, 0.08), (0.14, 0.22, 0.45),
                    (0.45, 0.47, 0.50), (0.90, 0.90, 0.90), (0.22, 0.33, 0.22), (0.70, 0.58, 0.22)], np.float32)


CLEAR_PATH_MARGIN_M = 1.5  # extra clearance of static objects from a keep-clear path (build_scene3d), metres


class Mat:
    """Material ids (the shader's `mat` attribute)."""

    GROUND, WALL, ROOF, FOLIAGE, TRUNK, CAR, GLASS, METAL, CONTACT_SHADOW = range(9)


@dataclass
class Mesh:
    """A flat triangle list (see the module docstring for the arrays' frames and units)."""

    pos: np.ndarray
    nrm: np.ndarray
    col: np.ndarray
    mat: np.ndarray
    uv: np.ndarray

    @classmethod
    def empty(cls) -> "Mesh":
        z = np.zeros((0, 3), np.float32)
        return cls(z, z.copy(), z.copy(), np.zeros(0, np.float32), np.zeros((0, 2), np.float32))

    def __len__(self) -> int:
        return len(self.pos)

    def interleaved(self) -> np.ndarray:
        """(N, 12) float32: pos, nrm, col, mat, uv (the vertex buffer layout '3f 3f 3f 1f 2f')."""
        return np.ascontiguousarray(np.c_[self.pos, self.nrm, self.col, self.mat, self.uv], dtype=np.float32)


class _Builder:
    """Accumulates triangles (and their attributes) into a `Mesh`."""

    def __init__(self) -> None:
        self.parts: list[tuple[np.ndarray, ...]] = []

    def tris(self, p: np.ndarray, col, mat: int, uv: np.ndarray | None = None, nrm: np.ndarray | None = None) -> None:
        """Triangles p (3k, 3) with one colour; normals from the winding (counter-clockwise seen from outside)."""
        p = np.asarray(p, np.float64).reshape(-1, 3, 3)
        if nrm is None:
            n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            nrm = np.repeat(n, 3, axis=0)
        k = len(p) * 3
        uv = np.zeros((k, 2)) if uv is None else np.asarray(uv).reshape(k, 2)
        self.parts.append((p.reshape(k, 3), np.asarray(nrm).reshape(k, 3), np.broadcast_to(np.asarray(col, np.float64), (k, 3)),
                           np.full(k, float(mat)), uv))

    def quad(self, a, b, c, d, col, mat: int, uv: np.ndarray | None = None) -> None:
        """Quad a-b-c-d (counter-clockwise from outside) as two triangles; uv (4, 2) per corner."""
        self.tris(np.array([a, b, c, a, c, d]), col, mat, None if uv is None else np.asarray(uv)[[0, 1, 2, 0, 2, 3]])

    def box(self, centre: np.ndarray, axis: np.ndarray, length: float, width: float, z0: float, z1: float,
            col, mat: int, top_col=None, top_mat: int | None = None) -> None:
        """An oriented box (no bottom): `length` along unit `axis` (2,), `width` across, from z0 to z1."""
        c = _rect(np.asarray(centre, np.float64), np.asarray(axis, np.float64), length, width)
        self.prism(c, z0, z1, col, mat)
        self.quad(*[np.r_[q, z1] for q in c], top_col if top_col is not None else col,
                  mat if top_mat is None else top_mat)

    def prism(self, ring: np.ndarray, z0: float, z1: float, col, mat: int, u0: float = 0.0) -> float:
        """Walls of a vertical prism over the counter-clockwise ring (K, 2); returns the perimeter + u0."""
        u = u0
        for a, b in zip(ring, np.roll(ring, -1, axis=0)):
            L = float(np.linalg.norm(b - a))
            self.quad(np.r_[a, z0], np.r_[b, z0], np.r_[b, z1], np.r_[a, z1], col, mat,
                      uv=np.array([(u, z0), (u + L, z0), (u + L, z1), (u, z1)]))
            u += L
        return u

    def mesh(self) -> Mesh:
        if not self.parts:
            return Mesh.empty()
        cols = list(zip(*self.parts))
        return Mesh(*(np.ascontiguousarray(np.concatenate(c), dtype=np.float32) for c in cols))


def _rect(centre: np.ndarray, axis: np.ndarray, along: float, across: float) -> np.ndarray:
    """Counter-clockwise corners (4, 2) of a rectangle `along` metres on unit `axis`, `across` metres wide."""
    perp = np.array([-axis[1], axis[0]])
    a, b = axis * along / 2.0, perp * across / 2.0
    return np.array([centre - a - b, centre + a - b, centre + a + b, centre - a + b])


def _ccw(c: np.ndarray) -> np.ndarray:
    x, y = c[:, 0], c[:, 1]
    return c if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0 else c[::-1]


def _icosphere(subdivisions: int) -> np.ndarray:
    """Unit icosphere (20 x 4^subdivisions faces) as triangles (F, 3, 3), counter-clockwise from outside."""
    t = (1.0 + 5 ** 0.5) / 2.0
    v = np.array([(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
                  (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)], np.float64)
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    tri = v[np.array(f)]
    tri /= np.linalg.norm(tri, axis=2, keepdims=True)
    for _ in range(subdivisions):
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        ab, bc, ca = (a + b), (b + c), (c + a)
        ab, bc, ca = (x / np.linalg.norm(x, axis=1, keepdims=True) for x in (ab, bc, ca))
        tri = np.concatenate([np.stack(s, 1) for s in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tri


_SPHERE = _icosphere(0)  # 20 faces: a software rasteriser's vertex budget; smooth normals round it


def _building(bld, rng: np.random.Generator, out: _Builder) -> None:
    c = _ccw(np.asarray(bld.corners, np.float64))
    h = float(bld.height_m)
    facade = FACADES[rng.integers(len(FACADES))] * rng.uniform(0.9, 1.1)
    roof = np.asarray(bld.colour, np.float64) / 255.0
    out.prism(c, 0.0, h, facade, Mat.WALL, u0=float(rng.uniform(0, 3)))
    if bld.gable:
        if np.linalg.norm(c[1] - c[0]) < np.linalg.norm(c[3] - c[0]):
            c = np.roll(c, -1, axis=0)
        a, b, cc, d = c
        rise = 0.3 * float(np.linalg.norm(d - a))
        m0, m1 = 0.5 * (a + d), 0.5 * (b + cc)
        z = lambda q, zz: np.r_[q, zz]  # noqa: E731
        out.quad(z(a, h), z(b, h), z(m1, h + rise), z(m0, h + rise), roof, Mat.ROOF)
        out.quad(z(cc, h), z(d, h), z(m0, h + rise), z(m1, h + rise), roof, Mat.ROOF)
        for p, q, m in ((b, cc, m1), (d, a, m0)):  # gable ends (facade)
            L = float(np.linalg.norm(q - p))
            out.tris(np.array([z(p, h), z(q, h), z(m, h + rise)]), facade, Mat.WALL,
                     uv=np.array([(0, h), (L, h), (L / 2, h + rise)]))
    else:
        out.quad(*[np.r_[q, h] for q in c], roof, Mat.ROOF)
        ctr = c.mean(axis=0)
        e1 = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
        for _ in range(int(rng.integers(0, 4))):
            q = ctr + (c[1] - c[0]) * rng.uniform(-0.3, 0.3) + (c[3] - c[0]) * rng.uniform(-0.3, 0.3)
            col = (0.18, 0.22, 0.32) if rng.random() < 0.4 else (0.78, 0.78, 0.77)
            out.box(q, e1, float(rng.uniform(1.2, 4.0)), float(rng.uniform(1.2, 4.0)), h, h + float(rng.uniform(0.8, 2.0)),
                    (0.6, 0.6, 0.6), Mat.METAL, top_col=col)


def _tree(x: float, y: float, r: float, rng: np.random.Generator, out: _Builder) -> None:
    bottom = float(rng.uniform(2.2, 3.0))
    half_h = r * float(rng.uniform(0.8, 1.05))
    ring = np.c_[np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)] * (0.12 + 0.04 * r) + (x, y)
    out.prism(ring, 0.0, bottom + half_h, (0.30, 0.24, 0.18), Mat.TRUNK)
    tri = _SPHERE.reshape(-1, 3)
    key = np.round(tri * 1e4).astype(np.int64)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    jitter = rng.uniform(0.82, 1.12, inv.max() + 1)[inv.ravel()][:, None]  # same jitter for shared vertices
    p = tri * jitter * np.array([r, r, half_h]) + np.array([x, y, bottom + half_h])
    nrm = tri / np.linalg.norm(tri, axis=1, keepdims=True)  # smooth normals: a rounded crown
    tone = float(rng.uniform(0.8, 1.2))
    out.tris(p, np.array([0.16, 0.30, 0.10]) * tone, Mat.FOLIAGE, nrm=nrm)


def car_mesh(colour) -> Mesh:
    """One car at the origin facing +x: body 4.3 x 1.8 x 0.8 m from 0.25 m, cabin 2.3 x 1.6 x 0.55 m above, and a
    contact shadow on the ground (moving cars are left out of the shadow map)."""
    b = _Builder()
    ax = np.array([1.0, 0.0])
    h = 0.5 * np.array([CAR_L + 0.4, CAR_W + 0.4])
    b.quad((-h[0], -h[1], 0.03), (h[0], -h[1], 0.03), (h[0], h[1], 0.03), (-h[0], h[1], 0.03), (0, 0, 0), Mat.CONTACT_SHADOW)
    b.box(np.zeros(2), ax, CAR_L, CAR_W, 0.25, 1.05, colour, Mat.CAR)
    b.box(np.array([-0.25, 0.0]), ax, 2.3, 1.6, 1.05, 1.5, (0.08, 0.09, 0.11), Mat.GLASS, top_col=colour, top_mat=Mat.CAR)
    return b.mesh()


def _place(mesh: Mesh, x: float, y: float, heading: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(heading), np.sin(heading)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32)
    return mesh.pos @ R.T + np.array([x, y, 0], np.float32), mesh.nrm @ R.T


def _cars(cars: list[tuple[float, float, float, int]]) -> Mesh:
    """Parked cars (x, y, heading, colour index) as one mesh."""
    if not cars:
        return Mesh.empty()
    parts = []
    templates = {k: car_mesh(CAR_RGB[k]) for k in range(len(CAR_RGB))}
    for x, y, th, k in cars:
        m = templates[k]
        p, n = _place(m, x, y, th)
        parts.append(Mesh(p, n, m.col, m.mat, m.uv))
    return Mesh(*(np.concatenate([getattr(m, f) for m in parts]) for f in ("pos", "nrm", "col", "mat", "uv")))


@dataclass
class MovingCars:
    """Cars driving along roads. xy: concatenated road polylines (P, 2) local metres with `start` (M + 1,)
    offsets (car i drives xy[start[i]:start[i+1]], already reversed for cars driving against the polyline);
    lane: lateral offset to the right, metres; s0: arc length at t = 0, metres; speed: m/s; colour: index."""

    xy: np.ndarray
    start: np.ndarray
    lane: np.ndarray
    s0: np.ndarray
    speed: np.ndarray
    colour: np.ndarray

    def __len__(self) -> int:
        return len(self.s0)


def moving_cars_at(mc: MovingCars, t: float | np.ndarray) -> np.ndarray:
    """Poses (M, 3) x, y, heading (local metres, ENU rad) of the moving cars at time t (s); with an array t
    of shape (T,), shape (M, T, 3)."""
    t = np.asarray(t, np.float64)
    out = np.zeros((len(mc),) + t.shape + (3,))
    for i in range(len(mc)):
        xy = mc.xy[mc.start[i]:mc.start[i + 1]]
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        s = np.r_[0.0, np.cumsum(seg)]
        si = np.mod(mc.s0[i] + mc.speed[i] * t, s[-1])
        x, y = np.interp(si, s, xy[:, 0]), np.interp(si, s, xy[:, 1])
        k = np.clip(np.searchsorted(s, si) - 1, 0, len(seg) - 1)
        d = xy[k + 1] - xy[k]
        d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
        out[i, ..., 0] = x + d[..., 1] * mc.lane[i]
        out[i, ..., 1] = y - d[..., 0] * mc.lane[i]
        out[i, ..., 2] = np.arctan2(d[..., 1], d[..., 0])
    return out


@dataclass
class Scene3D:
    """static: buildings, trees, poles; parked: {epoch: parked cars}; moving: the moving cars."""

    static: Mesh
    parked: dict[str, Mesh]
    moving: MovingCars

    def to_npz(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {"static": self.static.interleaved()}
        for k, m in self.parked.items():
            out[f"parked_{k}"] = m.interleaved()
        for f in ("xy", "start", "lane", "s0", "speed", "colour"):
            out[f"moving_{f}"] = getattr(self.moving, f)
        return out

    @classmethod
    def from_npz(cls, z) -> "Scene3D":
        def mesh(a: np.ndarray) -> Mesh:
            a = np.asarray(a, np.float32).reshape(-1, 12)
            return Mesh(a[:, 0:3], a[:, 3:6], a[:, 6:9], a[:, 9], a[:, 10:12])

        parked = {k[len("parked_"):]: mesh(z[k]) for k in z.files if k.startswith("parked_")}
        mc = MovingCars(*(np.asarray(z[f"moving_{f}"]) for f in ("xy", "start", "lane", "s0", "speed", "colour")))
        return cls(mesh(z["static"]), parked, mc)


def _frame(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = np.gradient(xy, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    return s, d, np.c_[-d[:, 1], d[:, 0]]


def build_scene3d(scene: Scene, rng: np.random.Generator, ego_xy: np.ndarray | None = None,
                  ego_t: np.ndarray | None = None, epochs: tuple[str, ...] = ("camera", "aerial"),
                  clear_xy: np.ndarray | None = None) -> Scene3D:
    """The 3-D scene around `scene` (local metres). ego_xy (N, 2) / ego_t (N,): the ego vehicle's path and its
    times (s); objects keep clear of it (moving cars at the same time). epochs: parked-car days to draw.
    clear_xy (M, 2): more points static objects keep clear of (another vehicle's path: `build_world`'s
    keep_clear) by CLEAR_PATH_MARGIN_M more than of the ego path (such a path crosses kerbs at any angle and is
    driven to within a rover's cross-track error); moving cars do not."""
    ego = cKDTree(ego_xy) if ego_xy is not None and len(ego_xy) else None
    other = cKDTree(clear_xy) if clear_xy is not None and len(clear_xy) else None

    def clear(p: np.ndarray, r: float) -> bool:
        return (ego is None or ego.query(p)[0] > r) and (other is None or other.query(p)[0] > r + CLEAR_PATH_MARGIN_M)

    st = _Builder()
    for b in scene.buildings:
        _building(b, rng, st)
    for x, y, r in scene.trees:
        if clear(np.array([x, y]), 1.6):
            _tree(float(x), float(y), float(r), rng, st)
    junctions = np.asarray(scene.junctions).reshape(-1, 2)
    jtree = cKDTree(junctions) if len(junctions) else None
    # Street lamps on a share of the roads (one side), sign posts at some junction corners.
    for rd in scene.roads:
        if rng.random() < 0.5 or len(rd.xy) < 20:
            continue
        s, d, n = _frame(rd.xy)
        side = float(rng.choice([-1.0, 1.0]))
        step = float(rng.uniform(25.0, 35.0))
        for si in np.arange(step / 2, s[-1] - 5.0, step):
            i = int(np.searchsorted(s, si))
            off = rd.width_m / 2.0 + 0.5
            q = rd.xy[i] + side * n[i] * off
            if not clear(q, 1.5) or (jtree is not None and jtree.query(q)[0] < 10.0):
                continue
            ring = np.c_[np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)] * 0.09 + q
            top = float(rng.uniform(7.0, 8.0))
            st.prism(ring, 0.0, top, (0.42, 0.43, 0.45), Mat.METAL)
            arm = -side * n[i]
            st.box(q + arm * 0.9, arm, 1.8, 0.12, top - 0.1, top, (0.42, 0.43, 0.45), Mat.METAL)
            st.box(q + arm * 1.7, arm, 0.6, 0.3, top - 0.25, top - 0.05, (0.9, 0.9, 0.85), Mat.METAL)
    for j, p in enumerate(junctions):
        if rng.random() < 0.5:
            continue
        ang = rng.uniform(0, 2 * np.pi)
        q = p + (scene.junction_radius[j] + SIDEWALK_M * 0.6) * np.array([np.cos(ang), np.sin(ang)])
        if not clear(q, 1.5):
            continue
        ring = np.c_[np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)] * 0.05 + q
        st.prism(ring, 0.0, 2.6, (0.55, 0.56, 0.58), Mat.METAL)
        t = np.array([-np.sin(ang), np.cos(ang)])
        st.box(q + np.array([np.cos(ang), np.sin(ang)]) * 0.05, t, 0.7, 0.04, 2.0, 2.6,
               (0.85, 0.85, 0.85) if rng.random() < 0.5 else (0.15, 0.3, 0.7), Mat.METAL)

    # Parking: bays of the lots and kerb-side spaces on avenues, each with a car per epoch.
    spaces: list[tuple[float, float, float, float]] = []  # x, y, heading, occupancy probability
    for lot in scene.lots:
        c = lot.corners
        u = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
        v = (c[3] - c[0]) / np.linalg.norm(c[3] - c[0])
        L, D = np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[0])
        bands = [(D - 5.0, D)] if lot.rows == 1 else [(0.0, 5.0), (D - 5.0, D)]
        heading = float(np.arctan2(v[1], v[0]))
        for v0, v1 in bands:
            for k in range(int(L / 2.5)):
                q = c[0] + u * (k * 2.5 + 1.45) + v * (0.5 * (v0 + v1))
                spaces.append((q[0], q[1], heading + (np.pi if rng.random() < 0.5 else 0.0), lot.occupancy))
    for rd in scene.roads:
        if not rd.avenue:
            continue
        s, d, n = _frame(rd.xy)
        for side in (-1.0, 1.0):
            if rng.random() < 0.5:
                continue
            for si in np.arange(12.0, s[-1] - 12.0, 6.0):
                i = int(np.searchsorted(s, si))
                q = rd.xy[i] + side * n[i] * (rd.width_m / 2.0 - 1.1)
                if jtree is not None and jtree.query(q)[0] < 18.0:
                    continue
                heading = float(np.arctan2(d[i, 1], d[i, 0])) + (0.0 if side < 0 else np.pi)
                spaces.append((q[0], q[1], heading, 0.5))
    spaces = [sp for sp in spaces if clear(np.array(sp[:2]), 2.6)]
    parked: dict[str, Mesh] = {}
    prev_occ, prev_col = None, None
    for epoch in epochs:
        p = np.array([sp[3] for sp in spaces])
        occ = rng.random(len(spaces)) < p
        col = rng.integers(len(CAR_RGB), size=len(spaces))
        if prev_occ is not None:
            stay = rng.random(len(spaces)) < STAY
            occ = np.where(stay, prev_occ, occ)
            col = np.where(stay, prev_col, col)
        prev_occ, prev_col = occ, col
        parked[epoch] = _cars([(sp[0], sp[1], sp[2], int(k)) for sp, o, k in zip(spaces, occ, col) if o])

    # Moving cars: about one per 150 m of road, in the right-hand lane.
    xs, starts, lanes, s0s, speeds, cols = [], [0], [], [], [], []
    for rd in scene.roads:
        length = float(np.linalg.norm(np.diff(rd.xy, axis=0), axis=1).sum())
        for _ in range(int(rng.poisson(length / 150.0))):
            xy = rd.xy if rng.random() < 0.5 else rd.xy[::-1]
            lane = rd.width_m / 4.0 if not rd.avenue else rd.width_m / 4.0 + float(rng.choice([-0.9, 0.9]))
            car = MovingCars(xy, np.array([0, len(xy)]), np.array([lane]), np.array([rng.uniform(0, length)]),
                             np.array([rng.uniform(5.0, 12.0)]), np.array([rng.integers(len(CAR_RGB))]))
            if ego_xy is not None and len(ego_xy) and ego_t is not None:
                tt = ego_t[:: max(1, len(ego_t) // 4000)]
                pose = moving_cars_at(car, tt)[0]
                ego_at = ego_xy[:: max(1, len(ego_t) // 4000)]
                if np.min(np.linalg.norm(pose[:, :2] - ego_at, axis=1)) < 3.0:
                    continue
            xs.append(xy)
            starts.append(starts[-1] + len(xy))
            lanes.append(lane), s0s.append(car.s0[0]), speeds.append(car.speed[0]), cols.append(car.colour[0])
    moving = MovingCars(np.concatenate(xs) if xs else np.zeros((0, 2)), np.asarray(starts, np.int64),
                        np.asarray(lanes), np.asarray(s0s), np.asarray(speeds), np.asarray(cols, np.int64))
    static = st.mesh()
    log.info("scene3d: %d buildings, %d trees, %d parking spaces, %d moving cars, %d static triangles",
             len(scene.buildings), len(scene.trees), len(spaces), len(moving), len(static) // 3)
    return Scene3D(static, parked, moving)
