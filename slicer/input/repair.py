"""Mesh repairs in plain numpy: consistent face winding and small holes filled.

Only meshes that need a repair run this code, so it imports nothing beyond numpy
(scipy's graph routines or trimesh would cost more to import than the repair takes).
"""

from __future__ import annotations

import numpy as np


def _pairs(faces: np.ndarray, nv: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces across every edge shared by exactly two faces: (a, b, same) arrays (e,).

    ``same`` is True where both faces walk the edge in the same direction, i.e.
    one of them must be flipped for the winding to agree.
    """
    a = faces.reshape(-1).astype(np.int64)
    b = faces[:, [1, 2, 0]].reshape(-1).astype(np.int64)
    key = np.minimum(a, b) * nv + np.maximum(a, b)
    forward = a < b
    order = np.argsort(key, kind="stable")
    key = key[order]
    start = np.ones(len(key), dtype=bool)
    start[1:] = key[1:] != key[:-1]
    first = np.flatnonzero(start)
    counts = np.diff(np.append(first, len(key)))
    two = first[counts == 2]
    i, j = order[two], order[two + 1]
    return i // 3, j // 3, forward[i] == forward[j]


def winding_flips(faces: np.ndarray, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """Which faces to flip for a consistent winding, and each face's patch.

    ``faces`` (f, 3) int64 over ``nv`` vertices. Faces joined by manifold edges
    form patches (edges shared by one or three or more faces join nothing); in
    each patch the faces are set relative to the patch's lowest face by a
    union-find that carries the parity of each face against its root: every
    round hooks the larger root of each disagreeing pair onto the smaller one
    (one pair per root, chosen by sort), then jumps pointers to the roots,
    accumulating parities. Returns ``flip`` (f,) bool relative to each root and
    ``root`` (f,) int64.
    """
    n = len(faces)
    u, v, same = _pairs(faces, nv)
    want = same.astype(np.uint8)
    parent = np.arange(n, dtype=np.int64)
    parity = np.zeros(n, dtype=np.uint8)
    while True:
        ru, rv = parent[u], parent[v]
        differ = ru != rv
        if not differ.any():
            break
        u, v, want = u[differ], v[differ], want[differ]
        ru, rv = ru[differ], rv[differ]
        q = parity[u] ^ parity[v] ^ want  # needed: flip(ru) ^ flip(rv)
        hi, lo = np.maximum(ru, rv), np.minimum(ru, rv)
        order = np.lexsort((lo, hi))
        hi, lo, q = hi[order], lo[order], q[order]
        head = np.ones(len(hi), dtype=bool)
        head[1:] = hi[1:] != hi[:-1]
        parent[hi[head]] = lo[head]
        parity[hi[head]] = q[head]
        while True:  # pointer jumping, parities summed along the way
            up = parent[parent]
            if np.array_equal(up, parent):
                break
            parity ^= parity[parent]
            parent = up
    return parity.astype(bool), parent


def fix_winding(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Faces (f, 3) int64 wound consistently within each patch of manifold edges, and
    how many were turned.

    Of the two ways to wind a patch, the one that keeps more of its area as
    written is chosen (an exporter that flipped some faces got most right);
    whether the whole model then points outwards is checked after, by volume.
    """
    flip, root = winding_flips(faces, len(vertices))
    if not flip.any():
        return faces, 0
    tri = vertices[faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    flipped_area = np.bincount(root, weights=area * flip, minlength=len(faces))
    total_area = np.bincount(root, weights=area, minlength=len(faces))
    invert = flipped_area > total_area / 2.0  # per root: flip the others instead
    flip ^= invert[root]
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out, int(flip.sum())


def fill_small_holes(faces: np.ndarray, nv: int, open_keys: np.ndarray) -> tuple[np.ndarray, int]:
    """Close holes bounded by three or four open edges with one or two new faces.

    ``open_keys`` are the sorted undirected keys (``lo * nv + hi``) of the open
    edges; the faces' directed edges on them, looked up in that small array,
    give each rim edge with its direction. A hole's rim is walked through a
    successor map over those edges (vectorised), and only rims that close
    after three or four steps are filled, wound to match their neighbours.
    Returns the faces (new ones appended) and the number of open edges closed.
    """
    n = len(faces)
    ra_parts, rb_parts, rf_parts = [], [], []
    for j in range(3):
        a = faces[:, j].astype(np.int64)
        b = faces[:, (j + 1) % 3].astype(np.int64)
        und = np.minimum(a, b) * nv + np.maximum(a, b)
        pos = np.minimum(np.searchsorted(open_keys, und), len(open_keys) - 1)
        on_rim = open_keys[pos] == und
        ra_parts.append(a[on_rim])
        rb_parts.append(b[on_rim])
        rf_parts.append(np.flatnonzero(on_rim))
    ra, rb = np.concatenate(ra_parts), np.concatenate(rb_parts)
    rim_face = np.concatenate(rf_parts)
    if len(ra) == 0 or n == 0:
        return faces, 0
    # the rim continues from rb at the open edge starting there (unique starts only)
    order = np.argsort(ra, kind="stable")
    starts = ra[order]
    unique = np.ones(len(starts), dtype=bool)
    unique[1:] = starts[1:] != starts[:-1]
    unique[:-1] &= starts[1:] != starts[:-1]

    def step(v: np.ndarray) -> np.ndarray:
        i = np.minimum(np.searchsorted(starts, v), len(starts) - 1)
        ok = (starts[i] == v) & unique[i]
        return np.where(ok, rb[order[i]], -1)

    v1 = rb
    v2 = step(v1)
    v3 = np.where(v2 >= 0, step(np.maximum(v2, 0)), -1)
    v4 = np.where(v3 >= 0, step(np.maximum(v3, 0)), -1)
    # one face per triangle, from its lowest vertex; a triangle whose rim is one face's
    # three edges is a lone triangle, not a hole (closing it would make a body of no
    # volume): left open
    i1 = np.minimum(np.searchsorted(starts, v1), len(starts) - 1)
    lone = rim_face[order[i1]] == rim_face
    tri = (v3 == ra) & (ra < np.minimum(v1, v2)) & ~lone
    quad = (v4 == ra) & (v3 != ra) & (ra < np.minimum(np.minimum(v1, v2), v3))
    new = [np.stack([ra[tri], v2[tri], v1[tri]], axis=1)]
    new.append(np.stack([ra[quad], v3[quad], v2[quad]], axis=1))
    new.append(np.stack([ra[quad], v2[quad], v1[quad]], axis=1))
    added = np.concatenate(new).astype(np.int64)
    if len(added) == 0:
        return faces, 0
    return np.concatenate([faces, added]), int(3 * tri.sum() + 4 * quad.sum())


def weld_open_vertices(
    vertices: np.ndarray, faces: np.ndarray, open_keys: np.ndarray, tolerance: float
) -> tuple[np.ndarray, int]:
    """Faces with the ends of open edges that lie within ``tolerance`` mm of each other
    merged into one vertex, and how many vertices were merged away.

    CAD tools write each body of a multibody design, or each patch of a body, on
    its own, so corners that should be one differ in their last bits and the
    edges between them look open. Only vertices on open edges are compared;
    each group of vertices chained within the tolerance takes the
    lowest-numbered one's place. The caller drops the faces this makes
    degenerate.
    """
    nv = len(vertices)
    ends = np.unique(np.concatenate([open_keys // nv, open_keys % nv]))
    if len(ends) < 2:
        return faces, 0
    a, b = _close_pairs(vertices[ends], tolerance)
    if len(a) == 0:
        return faces, 0
    root = _components(len(ends), a, b)
    target = np.arange(nv, dtype=np.int64)
    target[ends] = ends[root]
    merged = int((root != np.arange(len(ends))).sum())
    return target[faces], merged


# neighbours in x order compared per point before the KD-tree takes over (a wall of
# open edges at one x has many points within the tolerance in x alone)
_MAX_X_NEIGHBOURS = 32


def _close_pairs(points: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) of ``points`` (n, 3) within ``tolerance`` of each other.

    Points sorted by x are compared with their next neighbours in that order
    while any is within the tolerance in x (few: the open edges' ends of a
    part are far apart); past :data:`_MAX_X_NEIGHBOURS` a KD-tree finds them.
    """
    order = np.argsort(points[:, 0], kind="stable")
    p = points[order]
    n = len(p)
    found_a, found_b = [], []
    active = np.arange(n - 1)
    for d in range(1, n):
        active = active[active + d < n]
        active = active[p[active + d, 0] - p[active, 0] <= tolerance]
        if len(active) == 0:
            break
        if d > _MAX_X_NEIGHBOURS:
            from scipy.spatial import cKDTree

            pairs = cKDTree(points).query_pairs(tolerance, output_type="ndarray")
            return pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
        near = np.linalg.norm(p[active + d] - p[active], axis=1) <= tolerance
        found_a.append(order[active[near]])
        found_b.append(order[active[near] + d])
    if not found_a:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    return np.concatenate(found_a).astype(np.int64), np.concatenate(found_b).astype(np.int64)


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The lowest node of each node's connected component, for edges ``a``-``b``."""
    parent = np.arange(n, dtype=np.int64)
    while True:
        pa, pb = parent[a], parent[b]
        differ = pa != pb
        if not differ.any():
            return parent
        a, b, pa, pb = a[differ], b[differ], pa[differ], pb[differ]
        hi, lo = np.maximum(pa, pb), np.minimum(pa, pb)
        np.minimum.at(parent, hi, lo)
        while True:  # pointer jumping to the roots
            up = parent[parent]
            if np.array_equal(up, parent):
                break
            parent = up
