"""Path ordering: seams of closed loops, nearest-neighbour order and joining of open paths.

All functions are pure: coordinates in, coordinates out, ``(k, 2) float64`` mm.
"""

from __future__ import annotations

import numpy as np
import shapely


def ring_points(ring: np.ndarray) -> np.ndarray:
    """Points of a closed ring without the repeated closing point: (k, 2)."""
    if len(ring) > 1 and bool((ring[0] == ring[-1]).all()):
        return ring[:-1]
    return ring


def start_ring_at(points: np.ndarray, index: int) -> np.ndarray:
    """The ring ``points`` (k, 2) rotated to begin at ``index`` and closed: (k + 1, 2)."""
    return np.concatenate([points[index:], points[:index], points[index : index + 1]])


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
    dx, dy = points[:, 0] - pos[0], points[:, 1] - pos[1]
    return int((dx * dx + dy * dy).argmin())


def order_open_paths(
    paths: list[np.ndarray], pos: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """Greedy nearest-neighbour order of open paths, each entered at its nearer end.

    ``paths``: open polylines (k, 2); ``pos`` (2,) where the nozzle is. Uses one
    KD-tree over all path ends, asking for a few more neighbours only when the
    nearest ones are already used. Returns the paths in order (reversed where
    entered from their end) and the final position.
    """
    from scipy.spatial import cKDTree  # only fields with curved paths need it

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
    paths: list[np.ndarray], region: shapely.Geometry, max_gap: float, slack: float = 0.0
) -> list[np.ndarray]:
    """Join consecutive ordered open paths whose ends lie within ``max_gap`` mm.

    The connecting segment is extruded, so it is joined only when it stays
    near ``region`` (the fill region): its middle within ``slack`` mm of it
    (its ends lie on the region's edge), checked for all joints in one
    vectorised call. ``region`` is prepared in place for that check, so it
    must be the caller's own geometry (not one shared with other threads).
    """
    if len(paths) < 2:
        return paths
    sizes = np.array([len(p) for p in paths])
    ends = np.cumsum(sizes)
    pts = np.concatenate(paths)
    a = pts[ends[:-1] - 1]  # each path's last point, but the last path's
    b = pts[ends[:-1]]  # each path's first point, but the first path's
    gap = np.linalg.norm(b - a, axis=1)
    near = gap <= max_gap
    if not near.any():
        return paths
    idx = np.flatnonzero(near)
    middle = shapely.points((a[idx] + b[idx]) / 2.0)
    ok = np.zeros(len(near), dtype=bool)
    # distance <= slack; a prepared region answers inside points without
    # measuring and indexes its edges for the others
    shapely.prepare(region)
    ok[idx] = shapely.dwithin(region, middle, slack)
    # a joined run is the stretch of the concatenated points between two refused joints
    cuts = ends[:-1][~ok]
    return np.split(pts, cuts)


def chord_levels(
    chords: np.ndarray, g: np.ndarray, d: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Level index and along-line interval of straight chords: (k (n,) int64, v0, v1 (n,) mm).

    ``chords`` (n, 2, 2) mm lie on lines ``H = x . g = k * spacing``; ``d`` is
    the direction along them; each interval has ``v0 <= v1``.
    """
    mid = chords.mean(axis=1)
    k = np.rint(mid @ g / spacing).astype(np.int64)
    va = chords[:, 0] @ d
    vb = chords[:, 1] @ d
    return k, np.minimum(va, vb), np.maximum(va, vb)


def order_chords(
    chords: np.ndarray, g: np.ndarray, d: np.ndarray, spacing: float, pos: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """Order parallel chords as zigzag stacks, stacks nearest first.

    A stack is a run of chords on consecutive levels whose along-line intervals
    overlap one to one (the usual boustrophedon cells between holes); inside a
    stack each chord is entered at the end nearest to where the previous one
    ended, so neighbouring ends are joinable. Stacks are visited greedily by
    nearest end. Links between levels are found for all chords at once with
    ``searchsorted``; only the walk along the (few) stacks is a Python loop.
    Returns the chords as (2, 2) arrays in print order and the final position.
    """
    n = len(chords)
    if n == 0:
        return [], pos
    k, v0, v1 = chord_levels(chords, g, d, spacing)
    order = np.lexsort((v0, k))
    chords, k, v0, v1 = chords[order], k[order], v0[order], v1[order]
    # position of each chord's level block, for lookups on the next level
    kmin = int(k.min())
    levels = k - kmin
    nlev = int(levels.max()) + 2
    start = np.searchsorted(levels, np.arange(nlev + 1))
    # candidates on the next level: chords b with v1_b > v0_a and v0_b < v1_a
    nb_lo = start[np.minimum(levels + 1, nlev)]
    nb_hi = start[np.minimum(levels + 2, nlev)]
    span = float(max(v1.max() - v0.min(), 1.0)) * 4.0
    key0 = levels * span + (v0 - v0.min())
    key1 = levels * span + (v1 - v0.min())
    first = np.maximum(np.searchsorted(key1, (levels + 1) * span + (v0 - v0.min()), "right"), nb_lo)
    last = np.minimum(np.searchsorted(key0, (levels + 1) * span + (v1 - v0.min()), "left"), nb_hi)
    count_up = np.maximum(last - first, 0)
    succ = np.where(count_up == 1, first, -1)
    # the successor must have this chord as its only overlapping chord below
    preds = np.bincount(succ[succ >= 0], minlength=n)
    has_pred = np.zeros(n, dtype=bool)
    ok = succ >= 0
    ok[ok] = preds[succ[ok]] == 1
    succ = np.where(ok, succ, -1)
    has_pred[succ[succ >= 0]] = True
    del key0, key1
    heads = np.flatnonzero(~has_pred)
    # head and depth of every chord's stack, by pointer doubling down the links
    pred = np.full(n, -1, dtype=np.int64)
    pred[succ[succ >= 0]] = np.flatnonzero(succ >= 0)
    root = np.where(pred >= 0, pred, np.arange(n))
    depth = (pred >= 0).astype(np.int64)
    jump = pred.copy()
    active = np.flatnonzero(jump >= 0)
    while len(active):
        hop = jump[active]
        depth[active] += depth[hop]
        root[active] = root[hop]
        jump[active] = jump[hop]
        active = active[jump[active] >= 0]
    stack_of = np.searchsorted(heads, root)
    seq = np.lexsort((depth, stack_of))  # chords stack by stack, bottom to top
    bounds = np.searchsorted(stack_of[seq], np.arange(len(heads) + 1))
    fw = _forward(chords, d)  # each chord along d; a zigzag alternates from there
    first, last = seq[bounds[:-1]], seq[bounds[1:] - 1]
    ends = np.stack([fw[first, 0], fw[first, 1], fw[last, 0], fw[last, 1]], axis=1)  # (s, 4, 2)
    visits = _visit_stacks(ends, fw, first, last, np.diff(bounds), pos)
    # every stack's chords, walked from the corner it is entered at, alternating
    s_of, corner = visits[:, 0], visits[:, 1]
    sizes = bounds[s_of + 1] - bounds[s_of]
    stack = np.repeat(np.arange(len(visits)), sizes)
    j = np.arange(n) - np.repeat(np.cumsum(sizes) - sizes, sizes)  # position in its stack
    c = corner[stack]
    src = np.where(c >= 2, bounds[s_of + 1][stack] - 1 - j, bounds[s_of][stack] + j)
    block = fw[seq[src]]
    flip = (j + c) % 2 == 1
    block[flip] = block[flip][:, ::-1]
    return list(block), block[-1, 1]


# stacks up to this many are ordered from one precomputed table of distances
_TABLE_STACKS = 64


def _visit_stacks(
    ends: np.ndarray,
    fw: np.ndarray,
    first: np.ndarray,
    last: np.ndarray,
    sizes: np.ndarray,
    pos: np.ndarray,
) -> np.ndarray:
    """Greedy nearest-corner order of zigzag stacks: (s, 2) int64 rows (stack, corner).

    ``ends`` (s, 4, 2) the corners a stack can be entered at; ``fw`` the
    chords along ``d``; ``first``/``last`` each stack's bottom and top chord;
    ``sizes`` its chord count. Entered at corner ``c``, a stack of ``L``
    chords is left at the far end of its last chord, which is turned back
    when ``L + c`` is even. The squared distances from every exit to every
    corner are computed at once (small stacks counts), so the walk itself
    only picks minima.
    """
    s = len(ends)
    here = np.asarray(pos, dtype=np.float64)
    if s == 1:
        dist = np.einsum("ijk,ijk->ij", ends - here, ends - here)
        return np.array([[0, int(dist[0].argmin())]], dtype=np.int64)
    # exits[s, c]: where the nozzle is after stack s entered at corner c
    end_chord = np.stack([fw[last], fw[last], fw[first], fw[first]], axis=1)  # (s, 4, 2, 2)
    turned = (sizes[:, None] + np.arange(4)[None, :]) % 2 == 0
    exits = np.where(turned[:, :, None], end_chord[:, :, 0], end_chord[:, :, 1])
    exits = exits.reshape(4 * s, 2)
    table = None
    if s <= _TABLE_STACKS:
        # table[i, a]: corner i from exit a, (4s, 4s), so that a visited stack's
        # corners are contiguous rows; x and y apart, as einsum is slow on a
        # last axis of two (the sums are the same to the bit)
        corners = ends.reshape(4 * s, 2)
        dx = corners[:, None, 0] - exits[None, :, 0]
        dy = corners[:, None, 1] - exits[None, :, 1]
        table = dx * dx + dy * dy
    penalty = np.zeros(4 * s)
    dist = np.einsum("ijk,ijk->ij", ends - here, ends - here).ravel()
    picks = []
    for _ in range(s):
        pick = int(dist.argmin())
        picks.append(pick)
        # the corners of a visited stack are ruled out by an infinite distance
        k = pick >> 2
        if table is not None:
            table[4 * k : 4 * k + 4] = np.inf
            dist = table[:, pick]
        else:
            penalty[4 * k : 4 * k + 4] = np.inf
            here = exits[pick]
            dist = np.einsum("ijk,ijk->ij", ends - here, ends - here).ravel() + penalty
    flat = np.array(picks, dtype=np.int64)
    return np.stack([flat >> 2, flat & 3], axis=1)


def _forward(chords: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Chords (n, 2, 2) each turned to run along ``d`` (a copy)."""
    out = chords.copy()
    back = (chords[:, 1] - chords[:, 0]) @ d < 0
    out[back] = out[back][:, ::-1]
    return out
