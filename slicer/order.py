"""Path ordering: seams of closed loops, nearest-neighbour order and joining of open paths.

All functions are pure: coordinates in, coordinates out, ``(k, 2) float64`` mm.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree


def ring_points(ring: np.ndarray) -> np.ndarray:
    """Points of a closed ring without the repeated closing point: (k, 2)."""
    if len(ring) > 1 and np.array_equal(ring[0], ring[-1]):
        return ring[:-1]
    return ring


def start_ring_at(points: np.ndarray, index: int) -> np.ndarray:
    """The ring ``points`` (k, 2) rotated to begin at ``index`` and closed: (k + 1, 2)."""
    rolled = np.roll(points, -index, axis=0)
    return np.concatenate([rolled, rolled[:1]])


def rear_seam(points: np.ndarray) -> int:
    """Index of the seam vertex of an outer wall: the rearmost (max y), then leftmost point.

    Aligning the outer walls' seams at the back of the part hides them and makes
    them the same from layer to layer.
    """
    y = np.round(points[:, 1], 3)
    candidates = np.flatnonzero(y == y.max())
    return int(candidates[np.argmin(points[candidates, 0])])


def nearest_vertex(points: np.ndarray, pos: np.ndarray) -> int:
    """Index of the vertex of ``points`` (k, 2) nearest to ``pos`` (2,)."""
    d = np.einsum("ij,ij->i", points - pos, points - pos)
    return int(np.argmin(d))


def order_open_paths(
    paths: list[np.ndarray], pos: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """Greedy nearest-neighbour order of open paths, each entered at its nearer end.

    ``paths``: open polylines (k, 2); ``pos`` (2,) where the nozzle is. Uses one
    KD-tree over all path ends, asking for a few more neighbours only when the
    nearest ones are already used. Returns the paths in order (reversed where
    entered from their end) and the final position.
    """
    n = len(paths)
    if n == 0:
        return [], pos
    ends = np.empty((2 * n, 2))
    ends[:n] = [p[0] for p in paths]
    ends[n:] = [p[-1] for p in paths]
    tree = cKDTree(ends)
    used = np.zeros(n, dtype=bool)
    out: list[np.ndarray] = []
    k = min(8, 2 * n)
    here = np.asarray(pos, dtype=np.float64)
    for _ in range(n):
        while True:
            _, idx = tree.query(here, k=k)
            idx = np.atleast_1d(idx)
            free = idx[~used[idx % n]]
            if len(free):
                hit = int(free[0])
                break
            if k >= 2 * n:
                remaining = np.flatnonzero(~used)
                cand = np.concatenate([remaining, remaining + n])
                d = np.einsum("ij,ij->i", ends[cand] - here, ends[cand] - here)
                hit = int(cand[np.argmin(d)])
                break
            k = min(2 * k, 2 * n)
        p = hit % n
        used[p] = True
        path = paths[p] if hit < n else paths[p][::-1]
        out.append(path)
        here = path[-1]
    return out, here


def join_paths(
    paths: list[np.ndarray], region: shapely.Geometry, max_gap: float
) -> list[np.ndarray]:
    """Join consecutive ordered open paths whose ends lie within ``max_gap`` mm.

    The connecting segment is extruded, so it is joined only when it stays
    inside ``region`` (the fill region, slightly grown), checked for all joints
    in one vectorised call.
    """
    if len(paths) < 2:
        return paths
    a = np.array([p[-1] for p in paths[:-1]])
    b = np.array([p[0] for p in paths[1:]])
    gap = np.linalg.norm(b - a, axis=1)
    near = gap <= max_gap
    if not near.any():
        return paths
    idx = np.flatnonzero(near)
    connectors = shapely.linestrings(np.stack([a[idx], b[idx]], axis=1))
    ok = np.zeros(len(near), dtype=bool)
    ok[idx] = shapely.covered_by(connectors, region)
    out: list[np.ndarray] = []
    current = [paths[0]]
    for i in range(1, len(paths)):
        if ok[i - 1]:
            current.append(paths[i])
        else:
            out.append(np.concatenate(current) if len(current) > 1 else current[0])
            current = [paths[i]]
    out.append(np.concatenate(current) if len(current) > 1 else current[0])
    return out
