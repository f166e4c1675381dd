"""Road network (a warped street grid with straight and curved streets) and a route through it with a revisit.

Frame: local ENU metres relative to the world centre (x east, y north). Polylines are sampled about every
metre. A route is a node sequence with no U-turns that ends by driving its first street again, so the path
passes the same place twice far apart in time (loop closure).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from taco_mav.errors import DataError

log = logging.getLogger(__name__)

__all__ = ["Road", "RoadNetwork", "grid_network", "plan_route", "route_polyline", "resample_polyline"]


@dataclass(frozen=True)
class Road:
    """One road segment. xy: centreline (N, 2) local ENU metres; width_m: carriageway width, metres;
    avenue: True for a wide road with a solid centre line, False for a street with a dashed one."""

    xy: np.ndarray
    width_m: float
    avenue: bool = False


@dataclass(frozen=True)
class RoadNetwork:
    """nodes: (K, 2) junction positions, local ENU metres; edges: (E, 2) node ids; roads[e] runs from
    nodes[edges[e, 0]] to nodes[edges[e, 1]]; junction_style[k]: 0 plain, 1 zebra crossings, 2 chequerboard,
    3 yellow box."""

    nodes: np.ndarray
    edges: np.ndarray
    roads: list[Road]
    junction_style: np.ndarray
    _adj: dict[int, list[tuple[int, int]]] = field(default_factory=dict, repr=False)

    def neighbours(self, node: int) -> list[tuple[int, int]]:
        """(neighbour node, edge id) pairs of `node`."""
        if not self._adj:
            for e, (a, b) in enumerate(self.edges):
                self._adj.setdefault(int(a), []).append((int(b), e))
                self._adj.setdefault(int(b), []).append((int(a), e))
        return self._adj.get(node, [])

    def edge_length(self, e: int) -> float:
        """Length of road e, metres."""
        return float(np.linalg.norm(np.diff(self.roads[e].xy, axis=0), axis=1).sum())


def resample_polyline(xy: np.ndarray, step: float) -> np.ndarray:
    """The polyline (N, 2) resampled at uniform arc-length `step` metres (end point kept)."""
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    keep = np.r_[True, seg > 1e-9]
    s, xy = s[keep], xy[keep]
    n = max(int(np.ceil(s[-1] / step)), 1)
    si = np.linspace(0.0, s[-1], n + 1)
    return np.c_[np.interp(si, s, xy[:, 0]), np.interp(si, s, xy[:, 1])]


def grid_network(rng: np.random.Generator, n_cols: int, n_rows: int,
                 spacing_m: tuple[float, float] = (70.0, 130.0)) -> RoadNetwork:
    """A warped street grid of n_cols x n_rows junctions centred on the origin.

    Block sizes are uniform in `spacing_m`; junctions are jittered and displaced by a smooth field so
    streets are not parallel; about a third of the segments bulge into curves; a few segments are dropped
    (keeping the graph connected and every junction of degree >= 2); every other grid line may be an avenue.
    """
    xs = np.r_[0.0, np.cumsum(rng.uniform(*spacing_m, n_cols - 1))]
    ys = np.r_[0.0, np.cumsum(rng.uniform(*spacing_m, n_rows - 1))]
    xs -= xs.mean()
    ys -= ys.mean()
    gx, gy = np.meshgrid(xs, ys)  # (n_rows, n_cols)
    ph = rng.uniform(0, 2 * np.pi, 2)
    amp = rng.uniform(8.0, 20.0, 2)
    dx = amp[0] * np.sin(2 * np.pi * gy / rng.uniform(500, 900) + ph[0])
    dy = amp[1] * np.sin(2 * np.pi * gx / rng.uniform(500, 900) + ph[1])
    nodes = np.c_[(gx + dx).ravel(), (gy + dy).ravel()] + rng.uniform(-5.0, 5.0, (n_rows * n_cols, 2))
    idx = np.arange(n_rows * n_cols).reshape(n_rows, n_cols)
    col_avenue = rng.random(n_cols) < 0.3
    row_avenue = rng.random(n_rows) < 0.3
    cand: list[tuple[int, int, bool]] = []
    for r in range(n_rows):
        for c in range(n_cols - 1):
            cand.append((idx[r, c], idx[r, c + 1], bool(row_avenue[r])))
    for r in range(n_rows - 1):
        for c in range(n_cols):
            cand.append((idx[r, c], idx[r + 1, c], bool(col_avenue[c])))
    keep = np.ones(len(cand), bool)
    k = len(nodes)
    for i in rng.permutation(len(cand))[: len(cand) // 12]:
        if cand[i][2]:
            continue  # avenues run through
        keep[i] = False
        e = np.array([c[:2] for c, kp in zip(cand, keep) if kp])
        deg = np.bincount(e.ravel(), minlength=k)
        g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(k, k))
        if deg.min() < 2 or connected_components(g, directed=False)[0] != 1:
            keep[i] = True
    roads: list[Road] = []
    edges = []
    for (a, b, avenue), kp in zip(cand, keep):
        if not kp:
            continue
        p, q = nodes[a], nodes[b]
        length = float(np.linalg.norm(q - p))
        u = np.linspace(0.0, 1.0, max(int(length), 2) + 1)[:, None]
        xy = p + u * (q - p)
        if not avenue and rng.random() < 0.35:
            normal = np.array([-(q - p)[1], (q - p)[0]]) / length
            xy = xy + np.sin(np.pi * u) * normal * rng.choice([-1, 1]) * rng.uniform(0.06, 0.12) * length
        width = float(rng.uniform(11.0, 13.0) if avenue else rng.uniform(6.5, 8.0))
        roads.append(Road(xy=resample_polyline(xy, 1.0), width_m=width, avenue=avenue))
        edges.append((a, b))
    style = rng.choice(4, size=k, p=[0.45, 0.3, 0.13, 0.12])
    return RoadNetwork(nodes=nodes, edges=np.array(edges, dtype=np.int64), roads=roads, junction_style=style)


MAX_TURN_RAD = np.radians(110.0)  # sharper turns (nearly U-turns through a junction) are never planned


def _tangents(net: RoadNetwork) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """For each directed edge (a, b): unit tangent leaving a and unit tangent arriving at b."""
    out = {}
    for e, (a, b) in enumerate(net.edges):
        xy = net.roads[e].xy
        k = min(6, len(xy) - 1)
        t0, t1 = xy[k] - xy[0], xy[-1] - xy[-1 - k]
        t0, t1 = t0 / np.linalg.norm(t0), t1 / np.linalg.norm(t1)
        out[(int(a), int(b))] = (t0, t1)
        out[(int(b), int(a))] = (-t1, -t0)
    return out


def _turn(tan: dict, a: int, b: int, c: int) -> float:
    """Absolute turn angle, radians, driving a -> b -> c."""
    t_in, t_out = tan[(a, b)][1], tan[(b, c)][0]
    return float(np.arccos(np.clip(t_in @ t_out, -1.0, 1.0)))


def _way_back(net: RoadNetwork, tan: dict, prev: int, cur: int, start: int, first: int) -> tuple[float, list[int]]:
    """Shortest legal way from cur (arrived from prev) to start, arriving not from `first` and leaving start
    towards `first` with a legal turn: Dijkstra over directed edges with turn restrictions."""
    states = list(tan)
    sid = {st: i for i, st in enumerate(states)}
    lengths = {(int(a), int(b)): net.edge_length(e) for e, (a, b) in enumerate(net.edges)}
    rows, cols, w = [], [], []
    for (a, b) in states:
        for c, _e in net.neighbours(b):
            if c != a and _turn(tan, a, b, c) <= MAX_TURN_RAD:
                rows.append(sid[(a, b)])
                cols.append(sid[(b, c)])
                w.append(lengths.get((b, c), lengths.get((c, b))))
    n = len(states)
    g = coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    src = sid[(prev, cur)]
    dist, pred = dijkstra(g, directed=True, indices=src, return_predecessors=True)
    best, best_i = np.inf, -1
    for (a, b), i in sid.items():
        if b == start and a != first and dist[i] < best and _turn(tan, a, start, first) <= MAX_TURN_RAD:
            best, best_i = float(dist[i]), i
    if best_i < 0:
        return np.inf, []
    chain = [best_i]
    while chain[-1] != src:
        chain.append(int(pred[chain[-1]]))
    return best, [states[i][1] for i in chain[::-1]][1:]


def plan_route(net: RoadNetwork, rng: np.random.Generator, length_m: float) -> list[int]:
    """A junction sequence of about `length_m` metres: a random walk without U-turns or turns sharper than
    110 degrees (straight on twice as likely as a turn, recently driven streets avoided), then the shortest
    legal way back to the start arriving from another street, then the first street again (the revisit)."""
    tan = _tangents(net)
    centre = int(np.argmin(np.linalg.norm(net.nodes, axis=1)))
    start = centre if len(net.neighbours(centre)) >= 3 else max(range(len(net.nodes)), key=lambda n: len(net.neighbours(n)))
    first = net.neighbours(start)[int(rng.integers(len(net.neighbours(start))))][0]
    route = [start, first]
    driven = {frozenset((start, first)): 0}
    e0 = float(np.linalg.norm(net.nodes[first] - net.nodes[start]))
    walked = e0
    while True:
        prev, cur = route[-2], route[-1]
        if walked + e0 >= 0.5 * length_m:
            back, tail = _way_back(net, tan, prev, cur, start, first)
            if np.isfinite(back) and walked + back + e0 >= length_m:
                return route + tail + [first]
        options, weights = [], []
        for nb, _e in net.neighbours(cur):
            if nb == prev or _turn(tan, prev, cur, nb) > MAX_TURN_RAD:
                continue
            w = 2.0 if _turn(tan, prev, cur, nb) < 0.5 else 1.0
            if len(route) - driven.get(frozenset((cur, nb)), -100) < 12:
                w *= 0.15
            options.append(nb)
            weights.append(w)
        if not options:  # only sharp turns left: take the least sharp
            options = [min((nb for nb, _ in net.neighbours(cur) if nb != prev), key=lambda c: _turn(tan, prev, cur, c))]
            weights = [1.0]
        p = np.asarray(weights) / np.sum(weights)
        nxt = options[int(rng.choice(len(options), p=p))]
        driven[frozenset((cur, nxt))] = len(route)
        walked += float(np.linalg.norm(net.nodes[nxt] - net.nodes[cur]))
        route.append(nxt)
        if walked > 3.0 * length_m + 5000.0:
            raise DataError("route planner: could not close the loop back to the start")


def route_polyline(net: RoadNetwork, route: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The road centreline along a route, (N, 2) local ENU metres; the indices into it of each junction
    passed; and (N,) the offset of the right-hand lane's middle to the right of the centreline (a quarter of
    the road width), metres."""
    lookup = {frozenset((int(a), int(b))): e for e, (a, b) in enumerate(net.edges)}
    parts: list[np.ndarray] = []
    offsets: list[np.ndarray] = []
    junction_idx: list[int] = []
    count = 0
    for a, b in zip(route[:-1], route[1:]):
        e = lookup[frozenset((a, b))]
        xy = net.roads[e].xy if net.edges[e, 0] == a else net.roads[e].xy[::-1]
        if parts:
            xy = xy[1:]
        junction_idx.append(count)
        parts.append(xy)
        offsets.append(np.full(len(xy), net.roads[e].width_m / 4.0))
        count += len(xy)
    junction_idx.append(count - 1)
    return np.vstack(parts), np.asarray(junction_idx), np.concatenate(offsets)
