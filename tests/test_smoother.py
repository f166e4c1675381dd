import math

import numpy as np

from taco_mav.core.params import SmootherParams
from taco_mav.core.smoother import FixNode, loop_closure_pairs, smooth


def _polyline(points, step=1.0):
    """Poses every `step` metres along a polyline (ENU), heading along the segment."""
    out = []
    for (x0, y0), (x1, y1) in zip(points[:-1], points[1:]):
        seg = math.hypot(x1 - x0, y1 - y0)
        th = math.atan2(y1 - y0, x1 - x0)
        for k in range(int(round(seg / step))):
            out.append((x0 + k * step * math.cos(th), y0 + k * step * math.sin(th), th))
    out.append((*points[-1], out[-1][2]))
    return np.array(out)


def _increments(poses):
    inc = []
    for (x0, y0, t0), (x1, y1, t1) in zip(poses[:-1], poses[1:]):
        c, s = math.cos(t0), math.sin(t0)
        dx, dy = x1 - x0, y1 - y0
        inc.append((c * dx + s * dy, -s * dx + c * dy, math.atan2(math.sin(t1 - t0), math.cos(t1 - t0))))
    return np.array(inc)


def _fixes(poses, every, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    return [FixNode(i, poses[i, :2] + rng.normal(0, noise, 2) if noise else poses[i, :2].copy(), 1.5, 3.0)
            for i in range(0, len(poses), every)]


def _path_cum(poses):
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1))])


def test_a_loop_around_a_block_closes():
    poses = _polyline([(0, 0), (100, 0), (100, 100), (0, 100), (0, 0), (60, 0)])
    fixes = _fixes(poses, 20)
    pairs = loop_closure_pairs(fixes, _path_cum(poses))
    assert pairs, "the revisit of the start must close a loop"
    for a, b in pairs:
        assert np.linalg.norm(fixes[a].xy - fixes[b].xy) <= 50
        assert (_path_cum(poses)[fixes[b].node] - _path_cum(poses)[fixes[a].node]) >= 5 * np.linalg.norm(fixes[a].xy - fixes[b].xy)


def test_a_parallel_road_20m_away_adds_no_closure():
    # east on y = 0, a gentle 100 m lane shift onto the parallel road at y = 20, then east along it
    poses = _polyline([(0, 0), (300, 0), (400, 20), (700, 20)])
    assert loop_closure_pairs(_fixes(poses, 10), _path_cum(poses)) == []


def test_stop_and_go_adds_no_closure():
    moving = _polyline([(0, 0), (100, 0)])
    stopped = np.repeat(moving[-1:], 200, axis=0)  # 20 s stopped at 10 Hz, fixes every 2 s
    poses = np.vstack([moving, stopped, _polyline([(100, 0), (200, 0)])[1:]])
    fixes = _fixes(poses, 20, noise=0.5, seed=1)
    assert loop_closure_pairs(fixes, _path_cum(poses)) == []


def test_smoother_pulls_drifted_odometry_onto_the_fixes_and_uses_the_loop():
    truth = _polyline([(0, 0), (100, 0), (100, 100), (0, 100), (0, 0), (60, 0)])
    inc = _increments(truth)
    drifted = inc.copy()
    drifted[:, 2] += 0.002  # a gyro bias: the dead-reckoned path curls away
    initial = [truth[0]]
    for dx, dy, dth in drifted:
        x, y, th = initial[-1]
        initial.append((x + math.cos(th) * dx - math.sin(th) * dy, y + math.sin(th) * dx + math.cos(th) * dy, th + dth))
    initial = np.array(initial)
    fixes = _fixes(truth, 25, noise=0.5, seed=2)
    res = smooth(initial, drifted, np.full(len(drifted), 0.5), fixes, SmootherParams())
    err_before = np.sqrt(np.mean(np.sum((initial[:, :2] - truth[:, :2]) ** 2, axis=1)))
    err_after = np.sqrt(np.mean(np.sum((res.poses[:, :2] - truth[:, :2]) ** 2, axis=1)))
    assert err_before > 10.0
    assert err_after < 1.5
    assert res.loop_closures
    assert res.poses.shape == truth.shape
