"""Path ordering: seams of closed loops, nearest-neighbour order and joining of open paths.

All functions are pure: coordinates in, coordinates out, ``(k, 2) float64`` mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from slicer.geometry.geom import lengths, sorted_unique, split_rows


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
    gap = lengths(b - a)
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
    return split_rows(pts, cuts)


def join_runs(
    runs: list[tuple[np.ndarray, np.ndarray, int]],
    regions: np.ndarray,
    max_gap: float,
    slack: float = 0.0,
    laid: np.ndarray | None = None,
) -> list[list[np.ndarray]]:
    """:func:`join_paths` of many runs of ordered paths at once (one vectorised check).

    Each run is ``(points, ends, region)``: its paths' points concatenated
    (m, 2) mm, where each path ends in them (cumulative sizes, (q,) int) and
    the index into ``regions`` (r,) of the region its joints must stay near.
    Paths are joined only within a run. Returns each run's joined paths.
    ``regions`` are prepared in place: they must be the caller's own. With
    ``laid`` (len(runs),) float64, each run's joined paths' length (mm) is
    written into it.
    """
    if not runs:
        return []
    counts = np.array([len(r[1]) for r in runs])
    offsets = np.cumsum([0] + [len(r[0]) for r in runs])[:-1]
    pts = np.concatenate([r[0] for r in runs])
    ends = np.concatenate([r[1] + off for r, off in zip(runs, offsets, strict=True)])
    which = np.repeat(np.arange(len(runs)), counts)
    joint = np.ones(len(ends), dtype=bool)
    joint[np.cumsum(counts) - 1] = False  # a run's last path joins nothing
    a = pts[ends - 1]
    b = pts[np.minimum(ends, len(pts) - 1)]
    gap = lengths(b - a)
    cand = np.flatnonzero(joint & (gap <= max_gap))
    ok = np.zeros(len(ends), dtype=bool)
    if len(cand):
        region_of = np.array([r[2] for r in runs])[which[cand]]
        shapely.prepare(regions[sorted_unique(region_of)])
        middle = shapely.points((a[cand] + b[cand]) / 2.0)
        ok[cand] = shapely.dwithin(regions[region_of], middle, slack)
    if laid is not None:
        # every step from a point to the next within a run, less the gaps left unjoined
        # (a run's sum is its own: the same whatever other runs are joined beside it)
        step = lengths(np.diff(pts, axis=0))
        owner = np.repeat(np.arange(len(runs)), [len(r[0]) for r in runs])
        step[owner[1:] != owner[:-1]] = 0.0
        laid[:] = np.bincount(owner[:-1], step, minlength=len(runs))
        left = joint & ~ok
        laid -= np.bincount(which[left], gap[left], minlength=len(runs))
    pieces = split_rows(pts, ends[:-1][~ok[:-1]])
    per_run = np.bincount(which[~ok], minlength=len(runs))
    bounds = np.cumsum(per_run)
    return [pieces[e - c : e] for e, c in zip(bounds, per_run, strict=True)]


def chord_levels(
    chords: np.ndarray, g: np.ndarray, d: np.ndarray, spacing: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Level index and along-line interval of straight chords: (k (n,) int64, v0, v1 (n,) mm).

    ``chords`` (n, 2, 2) mm lie on lines ``H = x . g = k * spacing`` (``spacing`` one
    for all, or (n,) one per chord); ``d`` is
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
    nearest end. Returns the chords as (2, 2) arrays in print order and the
    final position (see :func:`chord_stacks` and :func:`walk_stacks`).
    """
    if len(chords) == 0:
        return [], pos
    stacks = chord_stacks(chords, np.zeros(len(chords), dtype=np.int64), 1, g, d, spacing)
    block, here = walk_stacks(stacks, 0, pos)
    return list(block), here


@dataclass(frozen=True)
class ChordStacks:
    """Zigzag stacks of the chords of several groups (islands), found for all at once.

    ``fw`` (n, 2, 2) the chords, each along ``d``; ``seq`` (n,) chord indices
    stack by stack, bottom to top; ``bounds`` (s + 1,) where each stack starts
    in ``seq``; ``ends`` (s, 4, 2) the corners a stack can be entered at;
    ``first``/``last`` (s,) its bottom and top chord; ``group_stacks``
    (groups + 1,) the first stack of each group (a group's stacks are
    consecutive).
    """

    fw: np.ndarray
    seq: np.ndarray
    bounds: np.ndarray
    ends: np.ndarray
    first: np.ndarray
    last: np.ndarray
    group_stacks: np.ndarray


def chord_stacks(
    chords: np.ndarray,
    group: np.ndarray,
    groups: int,
    g: np.ndarray,
    d: np.ndarray,
    spacing: float | np.ndarray,
) -> ChordStacks:
    """The zigzag stacks of parallel chords (n, 2, 2) mm, never across groups.

    ``group`` (n,) int64 in ``[0, groups)``: the island of each chord; ``spacing``
    the lines' (one, or (n,) one per chord: groups may differ). Links
    between levels are found for all chords at once with ``searchsorted``
    on exact integer keys (level, rank of the along-line coordinate); the
    levels of different groups are kept two apart so no link crosses groups.
    """
    n = len(chords)
    k, v0, v1 = chord_levels(chords, g, d, spacing)
    order = np.lexsort((v0, k, group))
    chords, k, v0, v1, group = chords[order], k[order], v0[order], v1[order], group[order]
    # levels counted from each group's lowest, groups apart by two empty levels
    gstart = np.searchsorted(group, np.arange(groups + 1))
    present = gstart[1:] > gstart[:-1]
    kmin = np.zeros(groups, dtype=np.int64)
    height = np.zeros(groups, dtype=np.int64)
    kmin[present] = k[gstart[:-1][present]]
    height[present] = k[gstart[1:][present] - 1] - kmin[present] + 3
    offset = np.cumsum(height) - height
    levels = k - kmin[group] + offset[group]
    nlev = int(levels.max()) + 2
    start = np.searchsorted(levels, np.arange(nlev + 1))
    # candidates on the next level: chords b with v1_b > v0_a and v0_b < v1_a
    nb_lo = start[np.minimum(levels + 1, nlev)]
    nb_hi = start[np.minimum(levels + 2, nlev)]
    rank, distinct = _ranks(np.concatenate([v0, v1]))
    r0, r1 = rank[:n], rank[n:]
    span = distinct + 1
    key0 = levels * span + r0
    key1 = levels * span + r1
    up = (levels + 1) * span
    first = np.maximum(np.searchsorted(key1, up + r0, "right"), nb_lo)
    last = np.minimum(np.searchsorted(key0, up + r1, "left"), nb_hi)
    count_up = np.maximum(last - first, 0)
    succ = np.where(count_up == 1, first, -1)
    # the successor must have this chord as its only overlapping chord below
    preds = np.bincount(succ[succ >= 0], minlength=n)
    has_pred = np.zeros(n, dtype=bool)
    ok = succ >= 0
    ok[ok] = preds[succ[ok]] == 1
    succ = np.where(ok, succ, -1)
    has_pred[succ[succ >= 0]] = True
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
    first_c, last_c = seq[bounds[:-1]], seq[bounds[1:] - 1]
    ends = np.concatenate([fw[first_c], fw[last_c]], axis=1)  # (s, 4, 2) corners
    group_stacks = np.searchsorted(group[heads], np.arange(groups + 1))
    return ChordStacks(fw, seq, bounds, ends, first_c, last_c, group_stacks)


def _ranks(values: np.ndarray) -> tuple[np.ndarray, int]:
    """Each value's rank among the distinct values (n,) int64, and how many are distinct:
    ``np.unique``'s inverse, from one sort."""
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    new = np.empty(len(values), dtype=bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    step = np.cumsum(new)
    rank = np.empty(len(values), dtype=np.int64)
    rank[order] = step - 1
    return rank, int(step[-1]) if len(step) else 0


def walk_stacks(
    stacks: ChordStacks, group: int, pos: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The chords of one group in print order from ``pos``: ((m, 2, 2) mm, final position).

    Stacks are visited greedily by nearest corner; each is walked from the
    corner it is entered at, alternating direction. (0, 2, 2) and ``pos``
    when the group has no chords.
    """
    s0, s1 = int(stacks.group_stacks[group]), int(stacks.group_stacks[group + 1])
    if s0 == s1:
        return np.empty((0, 2, 2)), pos
    if s1 - s0 == 1:  # one stack (most islands): entered at its nearest corner
        near = stacks.ends[s0:s1] - np.asarray(pos, dtype=np.float64)
        entry = int(np.einsum("ijk,ijk->ij", near, near)[0].argmin())  # as _visit_stacks
        a, z = int(stacks.bounds[s0]), int(stacks.bounds[s1])
        chosen = stacks.seq[a:z] if entry < 2 else stacks.seq[a:z][::-1]
        one = stacks.fw[chosen]
        odd = 1 - entry % 2  # chords j with j + entry odd are turned back
        one[odd::2] = one[odd::2, ::-1].copy()
        return one, one[-1, 1]
    b = stacks.bounds[s0 : s1 + 1]
    sizes = np.diff(b)
    visits = _visit_stacks(
        stacks.ends[s0:s1], stacks.fw, stacks.first[s0:s1], stacks.last[s0:s1], sizes, pos
    )
    s_of, corner = visits[:, 0], visits[:, 1]
    sz = sizes[s_of]
    m = int(sz.sum())
    stack = np.repeat(np.arange(len(visits)), sz)
    j = np.arange(m) - np.repeat(np.cumsum(sz) - sz, sz)  # position in its stack
    c = corner[stack]
    src = np.where(c >= 2, b[s_of + 1][stack] - 1 - j, b[s_of][stack] + j)
    block = stacks.fw[stacks.seq[src]]
    flip = (j + c) % 2 == 1
    block[flip] = block[flip][:, ::-1]
    return block, block[-1, 1]


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
