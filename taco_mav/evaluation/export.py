"""Trajectory export in TUM and KITTI formats so `evo_ape` can re-evaluate a run.

TUM: one line per pose, "t x y z qx qy qz qw" (seconds, metres, unit quaternion). KITTI: one line per pose, the
first three rows of the 4x4 pose matrix, row-major (12 numbers). Planar poses: z = 0, rotation about z by the
ENU heading. Positions are ENU metres relative to the origin (add the origin's UTM easting/northing to get
absolute UTM).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_tum(path: Path, t: np.ndarray, xy: np.ndarray, theta: np.ndarray) -> None:
    """Write a TUM trajectory file; t (N,) s, xy (N, 2) m, theta (N,) rad."""
    half = 0.5 * np.asarray(theta, dtype=float)
    rows = np.column_stack([t, xy[:, 0], xy[:, 1], np.zeros(len(t)), np.zeros(len(t)), np.zeros(len(t)),
                            np.sin(half), np.cos(half)])
    np.savetxt(path, rows, fmt="%.9f %.6f %.6f %.6f %.9f %.9f %.9f %.9f")


def write_kitti(path: Path, xy: np.ndarray, theta: np.ndarray) -> None:
    """Write a KITTI-odometry pose file; xy (N, 2) m, theta (N,) rad."""
    c, s = np.cos(theta), np.sin(theta)
    z = np.zeros(len(xy))
    o = np.ones(len(xy))
    rows = np.column_stack([c, -s, z, xy[:, 0], s, c, z, xy[:, 1], z, z, o, z])
    np.savetxt(path, rows, fmt="%.9e")


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read back a planar TUM file written by write_tum: (t, xy, theta)."""
    a = np.loadtxt(path, ndmin=2)
    return a[:, 0], a[:, 1:3], 2.0 * np.arctan2(a[:, 6], a[:, 7])
