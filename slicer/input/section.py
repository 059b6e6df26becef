"""Cut a triangle mesh by many horizontal planes at once and chain the cuts into loops.

This is trimesh's ``mesh_multiplane`` reorganised to be vectorised across layers
as well as within one: every (face, plane) pair that crosses is computed in one
numpy pass, instead of one pass over all faces per plane. Two things make the
loops close exactly, with no snapping tolerance:

* a vertex counts as above a plane only when ``z > plane`` (a symbolic
  perturbation: a vertex lying exactly on a plane is below it), so every face
  that crosses has exactly one edge going up and one going down;
* the crossing point on a mesh edge is computed from its two vertices in
  index order, so the two faces sharing that edge get bitwise the same point,
  and the segment ends carry the edge's identity as an integer key.

Segments are oriented by the face normal (solid on the left), so a loop's
successor is the segment that starts on the edge where this one ends. Loops are
the cycles of that successor map, ranked by pointer doubling (no per-point
Python loop). Open meshes leave open chains, returned separately.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the three edges of a triangle as (from, to) corner indices
_EDGE_FROM = np.array([0, 1, 2])
_EDGE_TO = np.array([1, 2, 0])


@dataclass(frozen=True)
class Chains:
    """Ordered cut chains of a block of layers.

    ``coords`` (n, 2) float64 mm: the points of all chains, chain after chain;
    ``offsets`` (c + 1,) int64: chain ``k`` is ``coords[offsets[k]:offsets[k+1]]``;
    ``layer`` (c,) int64: the layer of each chain; ``closed`` (c,) bool: a loop
    (its last point joins its first) or an open chain (open mesh);
    ``face`` (c,) int64: one mesh face the chain passes through (for its body).
    """

    coords: np.ndarray
    offsets: np.ndarray
    layer: np.ndarray
    closed: np.ndarray
    face: np.ndarray


def face_layer_ranges(
    vertex_z: np.ndarray, faces: np.ndarray, planes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which planes each face crosses: the half-open range ``[lo, hi)`` of plane indices.

    ``vertex_z`` (v,) float64 mm; ``faces`` (f, 3) int; ``planes`` (m,)
    float64 mm ascending. A face crosses plane ``p`` when ``min z <= p < max z``.
    Returns two (f,) int64 arrays. Works in steps of 2^20 faces (bounded temporaries).
    """
    n = len(faces)
    lo = np.empty(n, dtype=np.int64)
    hi = np.empty(n, dtype=np.int64)
    step = 1 << 20
    for a in range(0, n, step):
        z = vertex_z[faces[a : a + step]]  # (k, 3)
        lo[a : a + step] = np.searchsorted(planes, z.min(axis=1), side="left")
        hi[a : a + step] = np.searchsorted(planes, z.max(axis=1), side="left")
    return lo, hi


def cut_block(
    vertices: np.ndarray,
    faces: np.ndarray,
    planes: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    first: int,
    last: int,
) -> Chains:
    """Cut the faces by planes ``first..last-1`` and chain the segments.

    ``vertices`` (v, 3) float64 mm; ``faces`` (f, 3) int64; ``planes`` (m,)
    float64 mm; ``lo``/``hi`` (f,) from :func:`face_layer_ranges`.
    """
    a = np.maximum(lo, first)
    b = np.minimum(hi, last)
    count = b - a
    sel = np.nonzero(count > 0)[0]
    if len(sel) == 0:
        return _empty_chains()
    count = count[sel]
    total = int(count.sum())
    face_idx = np.repeat(sel, count)
    starts = np.cumsum(count) - count
    layer = np.repeat(a[sel], count) + (np.arange(total) - np.repeat(starts, count))
    del starts, count

    tri = faces[face_idx]  # (p, 3) vertex indices
    z = planes[layer]
    above = vertices[tri, 2] > z[:, None]  # (p, 3)
    up = ~above[:, _EDGE_FROM] & above[:, _EDGE_TO]  # (p, 3) edge j goes up
    down = above[:, _EDGE_FROM] & ~above[:, _EDGE_TO]
    rows = np.arange(total)
    e_start = np.argmax(down, axis=1)  # segment starts where the surface goes down
    e_end = np.argmax(up, axis=1)

    nv = np.int64(len(vertices))
    start_pt, start_key = _crossing(vertices, tri, rows, e_start, z, nv)
    end_pt, end_key = _crossing(vertices, tri, rows, e_end, z, nv)
    base = layer.astype(np.int64) * nv * nv
    start_key += base
    end_key += base
    del tri, above, up, down, rows, base
    return _chain(start_pt, end_pt, start_key, end_key, layer, face_idx)


def _crossing(
    vertices: np.ndarray,
    tri: np.ndarray,
    rows: np.ndarray,
    edge: np.ndarray,
    z: np.ndarray,
    nv: np.int64,
) -> tuple[np.ndarray, np.ndarray]:
    """Where each pair's chosen edge crosses its plane, and that edge's integer key.

    The point is computed from the edge's vertices in index order, so both
    faces sharing an edge get identical coordinates.
    """
    va = tri[rows, _EDGE_FROM[edge]]
    vb = tri[rows, _EDGE_TO[edge]]
    i = np.minimum(va, vb).astype(np.int64)
    j = np.maximum(va, vb).astype(np.int64)
    pi = vertices[i]
    pj = vertices[j]
    t = (z - pi[:, 2]) / (pj[:, 2] - pi[:, 2])
    pt = pi[:, :2] + t[:, None] * (pj[:, :2] - pi[:, :2])
    return pt, i * nv + j


def _chain(
    start_pt: np.ndarray,
    end_pt: np.ndarray,
    start_key: np.ndarray,
    end_key: np.ndarray,
    layer: np.ndarray,
    face_idx: np.ndarray,
) -> Chains:
    """Link segments end-to-start by edge key and order each chain (pointer doubling)."""
    n = len(start_key)
    order = np.argsort(start_key, kind="stable")
    sorted_keys = start_key[order]
    pos = np.searchsorted(sorted_keys, end_key)
    if n > 1 and bool((sorted_keys[1:] == sorted_keys[:-1]).any()):
        # an edge shared by four or more faces (bodies sharing an edge, a wall
        # given twice) starts and ends several segments: the k-th segment ending
        # on it (in index order) goes on with the k-th starting there, so every
        # segment has a successor and the loops close (any pairing keeps the
        # same winding)
        pos = pos + _rank_in_group(end_key)
    pos = np.minimum(pos, n - 1)
    succ = np.where(sorted_keys[pos] == end_key, order[pos], -1)
    del order, sorted_keys, pos
    idx = np.arange(n)
    succ[succ == idx] = -1
    # non-manifold edges can give a segment two predecessors: keep the first
    src = np.nonzero(succ >= 0)[0]
    _, keep = np.unique(succ[src], return_index=True)
    drop = np.ones(len(src), dtype=bool)
    drop[keep] = False
    succ[src[drop]] = -1
    src = np.nonzero(succ >= 0)[0]
    pred = np.full(n, -1, dtype=np.int64)
    pred[succ[src]] = src

    # every chain or loop is labelled by its lowest-numbered segment
    label = np.minimum(_reach_min(succ), _reach_min(pred))
    open_comp = np.zeros(n, dtype=bool)
    open_comp[label[succ < 0]] = True
    # cut every loop open just before its lowest-numbered segment (deterministic)
    loop_heads = np.flatnonzero((label == idx) & ~open_comp)
    succ[pred[loop_heads]] = -1

    # distance of every segment to the end of its chain, by pointer doubling
    dist = (succ >= 0).astype(np.int64)
    nxt = succ.copy()
    active = np.nonzero(nxt >= 0)[0]
    while len(active):
        step = nxt[active]
        dist[active] = dist[active] + dist[step]
        nxt[active] = nxt[step]
        active = active[nxt[active] >= 0]
    seq = np.lexsort((-dist, label))  # chain by chain, first segment first
    lab = label[seq]
    bounds = np.flatnonzero(np.diff(lab)) + 1
    first = np.concatenate(([0], bounds))
    comp = lab[first]
    closed = ~open_comp[comp]
    sizes = np.diff(np.append(first, n))
    # points: each segment's start; open chains add their last segment's end
    last_seg = seq[first + sizes - 1]
    extra = (~closed).astype(np.int64)
    out_sizes = sizes + extra
    offsets = np.concatenate(([0], np.cumsum(out_sizes)))
    coords = np.empty((int(offsets[-1]), 2), dtype=np.float64)
    # positions of segment starts in the output
    shift = np.repeat(offsets[:-1] - first, sizes)
    coords[np.arange(n) + shift] = start_pt[seq]
    ends_at = offsets[1:][~closed] - 1
    coords[ends_at] = end_pt[last_seg[~closed]]
    return Chains(
        coords=coords,
        offsets=offsets.astype(np.int64),
        layer=layer[seq[first]].astype(np.int64),
        closed=closed,
        face=face_idx[seq[first]].astype(np.int64),
    )


def _rank_in_group(keys: np.ndarray) -> np.ndarray:
    """Each key's rank among the equal keys before it in index order, (n,) int64."""
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    head = np.ones(len(ks), dtype=bool)
    head[1:] = ks[1:] != ks[:-1]
    first = np.maximum.accumulate(np.where(head, np.arange(len(ks)), 0))
    rank = np.empty(len(ks), dtype=np.int64)
    rank[order] = np.arange(len(ks)) - first
    return rank


def _reach_min(step: np.ndarray) -> np.ndarray:
    """Lowest index reachable from each node by following ``step`` (-1 ends), by doubling.

    ``step`` (n,) int64 maps each node to one neighbour; after ``log2(n)``
    rounds of pointer jumping each node knows the minimum over everything it
    reaches, which on a loop is the whole loop.
    """
    n = len(step)
    low = np.arange(n, dtype=np.int64)
    nxt = step.copy()
    active = np.flatnonzero(nxt >= 0)
    for _ in range(max(1, int(n).bit_length())):  # 2^rounds >= n covers any loop
        if len(active) == 0:
            break
        hop = nxt[active]
        mine = low[active]
        better = np.minimum(mine, low[hop])
        if np.array_equal(better, mine):
            # after r rounds low[i] is the minimum of the 2^r nodes from i on; when
            # no node gains from the next 2^r, the windows from i, i + 2^r, ...
            # already cover all i reaches, so every minimum is final
            break
        low[active] = better
        nxt[active] = nxt[hop]
        active = active[nxt[active] >= 0]
    return low


def _empty_chains() -> Chains:
    return Chains(
        coords=np.empty((0, 2)),
        offsets=np.zeros(1, dtype=np.int64),
        layer=np.empty(0, dtype=np.int64),
        closed=np.empty(0, dtype=bool),
        face=np.empty(0, dtype=np.int64),
    )
