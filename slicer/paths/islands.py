"""Per-island wall rings and infill domain, made once for islands that repeat layer after layer.

A layer's walls and infill domain are inward offsets of each island taken one
island at a time, so an island with the same coordinates as one sliced lately
(the islands of a prismatic part, the parts of a plate that keep their shape
while another one changes, letters standing on a base) has the same walls and
domain, bit for bit. They are kept per thread, keyed by the island's exact
coordinates (WKB) and the settings they depend on, for the last
:data:`KEEP` islands (fewer when large: :data:`KEEP_BYTES`) asked for in the thread's
last :data:`WINDOW` calls (a window of recent layers); only the islands
not seen lately are offset, all at once.
The geometry kept is private to its thread: a thread may prepare it in place.
A long-running host drops every thread's islands when a job ends
(:func:`forget_everywhere`): kept, they held an organic model's walls (tens of MB
over a few threads) until other islands pushed them out.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from typing import Any, cast

import numpy as np
import shapely

from slicer.geometry.inset import inset
from slicer.paths import loops

# islands kept per thread (most recently used), and the most of their WKB kept, bytes
# (the walls, rings and domain kept with an island take a few times its WKB)
KEEP = 2048
KEEP_BYTES = 4_000_000
# an island not asked for in this thread's last WINDOW calls is let go: the calls go
# layer by layer (a batch of layers' toolpaths, a skin block's window of domains), so
# the islands kept are those of a window of recent layers, not of the whole model
# (a print's walls kept grew some 15 kB a layer, up to the bytes above, per thread)
WINDOW = 64
# the most points of an outline whose infill domain is its islands' own (island_domains):
# a 16-layer skin block's window of 22 such layers stays within a few hundred islands
DOMAIN_POINTS = 1000
# arcs of offset corners: segments per quarter circle
_QUAD_SEGS = 6
# a thin island's second wall level would cover less than this fraction of what the
# outer wall's beads leave uncovered (empty, or specks where the island is thickest)
THIN_SECOND = 0.25
# the widest outer wall of a thin island, in line widths: an island that needs wider
# walls is left as it was (PrusaSlicer lays a third line there, Arachne's 2-to-3 step)
THIN_MAX = 1.375
# the narrowest outer wall of an island thinner than two lines, in line widths: the two
# sides of its w-wide ring would overlap (a band 0.5 mm across got 0.8 mm of beads);
# a narrower island keeps its w-wide ring
THIN_MIN = 0.5

# what one island yields: (outer wall width or NaN, infill domain, wall rings by level)
Island = tuple[float, Any, list[Any]]
# an island's WKB and the settings its geometry depends on
Key = tuple[bytes, tuple[Any, ...]]

class _Kept:
    """One thread's islands, least recently used first, with the bytes of WKB in their
    keys; the lock is held while the dictionary changes (another thread may clear it)."""

    def __init__(self) -> None:
        self.islands: OrderedDict[Key, Island] = OrderedDict()
        self.used: dict[Key, int] = {}  # the call that last asked for each island
        self.calls = 0
        self.size = 0
        self.lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.islands)

    def clear(self) -> None:
        with self.lock:
            self.islands.clear()
            self.used.clear()
            self.size = 0


_local = threading.local()
_every: weakref.WeakSet[_Kept] = weakref.WeakSet()  # each live thread's, to forget them all
_every_lock = threading.Lock()


def _kept() -> _Kept:
    """This thread's islands."""
    kept = getattr(_local, "kept", None)
    if kept is None:
        kept = _local.kept = _Kept()
        with _every_lock:
            _every.add(kept)
    return kept


def forget() -> None:
    """Drop this thread's kept islands (a benchmark's passes each start cold)."""
    _kept().clear()


def forget_everywhere() -> None:
    """Drop every thread's kept islands (a job ended: its islands are not the next one's).

    Safe while other threads slice: a thread goes on with the islands it found, and
    offsets again those it does not find."""
    with _every_lock:
        every = list(_every)
    for kept in every:
        kept.clear()


def island_geometry(
    islands: np.ndarray, w: float, perimeters: int, fill_distance: float, wall_order: str
) -> tuple[np.ndarray, np.ndarray, list[Any]]:
    """Outer wall width (p,) float64 mm (NaN: the line width ``w``), infill domain (p,)
    object array and wall rings (:func:`slicer.paths.loops.wall_loops`, p lists) of each island
    of ``islands`` (p,) Polygons, for ``perimeters`` walls ``w`` mm wide and the domain
    ``fill_distance`` mm inside the outline.

    Islands seen lately with the same settings come from this thread's cache; the
    others are offset in one vectorised pass, in their order.
    """
    p = len(islands)
    holder = _kept()
    kept = holder.islands
    tag = (w, perimeters, fill_distance, wall_order)
    keys = [(b, tag) for b in shapely.to_wkb(islands)]
    with holder.lock:
        found: list[Island | None] = [kept.get(k) for k in keys]
    miss = [i for i in range(p) if found[i] is None]
    made: dict[int, Island] = {}
    if miss:
        width, fill, rings = _offsets(islands[miss], w, perimeters, fill_distance, wall_order)
        made = {i: (float(width[j]), fill[j], rings[j]) for j, i in enumerate(miss)}
    with holder.lock:
        holder.calls += 1
        now, used = holder.calls, holder.used
        for i, island in made.items():
            if keys[i] not in kept:
                holder.size += len(keys[i][0])
            found[i] = kept.setdefault(keys[i], island)
        for k in keys:
            if k in kept:  # (unless another thread forgot them meanwhile)
                kept.move_to_end(k)
                used[k] = now
        while kept and (len(kept) > KEEP or holder.size > KEEP_BYTES
                        or used[next(iter(kept))] <= now - WINDOW):
            key = kept.popitem(last=False)[0]
            holder.size -= len(key[0])
            del used[key]
    got = cast(list[Island], found)
    widths = np.array([f[0] for f in got], dtype=np.float64)
    fills = np.empty(p, dtype=object)
    fills[:] = [f[1] for f in got]
    return widths, fills, [f[2] for f in got]


def island_domains(
    outlines: np.ndarray, w: float, perimeters: int, fill_distance: float, wall_order: str
) -> np.ndarray:
    """The infill domain of each of ``outlines`` (n,) (Multi)Polygons: (n,) object array
    of new geometries, a Polygon when one part is left, a MultiPolygon when several, an
    empty Polygon when none.

    An outline of at most :data:`DOMAIN_POINTS` points gets its islands' own domains
    (:func:`island_geometry`, so their walls are made and kept with them), gathered:
    the islands of an outline are disjoint, so their domains need no union, and a
    thin island whose walls fill it has none. A larger outline is buffered in whole,
    as its islands' walls would not stay kept until its toolpaths are made (a layer
    of thousands of loops). Which way a layer goes depends on the layer alone.
    """
    outlines = np.asarray(outlines, dtype=object)
    out = np.empty(len(outlines), dtype=object)
    out[:] = [shapely.Polygon()] * len(outlines)
    points = shapely.get_num_coordinates(outlines)
    large = points > DOMAIN_POINTS
    if large.any():
        out[large] = shapely.buffer(outlines[large], -fill_distance, quad_segs=_QUAD_SEGS)
    small = np.flatnonzero(~large & (points > 0))
    islands, owner = shapely.get_parts(outlines[small], return_index=True)
    if len(islands) == 0:
        return out
    _, fills, _ = island_geometry(islands, w, perimeters, fill_distance, wall_order)
    parts, within = shapely.get_parts(fills, return_index=True)
    keep = ~shapely.is_empty(parts)
    parts, whose = parts[keep], owner[within[keep]]
    counts = np.bincount(whose, minlength=len(small))
    rows = np.flatnonzero(counts)
    if len(rows):
        # new geometries: the kept ones are private to this thread, these may be shared
        gathered = shapely.multipolygons(parts, indices=np.searchsorted(rows, whose))
        single = counts[rows] == 1
        out[small[rows[~single]]] = gathered[~single]
        if single.any():
            out[small[rows[single]]] = shapely.get_geometry(gathered[single], 0)
    return out


def _offsets(
    islands: np.ndarray, w: float, perimeters: int, fill_distance: float, wall_order: str
) -> tuple[np.ndarray, np.ndarray, list[Any]]:
    """:func:`island_geometry` of ``islands`` (q,), made: walls are the level sets
    ``buffer(island, -c_k)``, ``c_k = (k + 1/2) w``, the domain ``buffer(island,
    -fill_distance)``."""
    levels = (np.arange(perimeters) + 0.5) * w
    walls = np.empty((len(islands), len(levels)), dtype=object)
    for k, level in enumerate(levels.tolist()):
        walls[:, k] = inset(islands, level, _QUAD_SEGS)
    outer_width = np.full(len(islands), np.nan)  # NaN: the settings' line width
    if perimeters >= 2:
        walls, outer_width = widen_thin_walls(islands, walls, w)
    # a widened wall fills its island: specks of infill domain would lie on it
    fill = np.full(len(islands), shapely.Polygon(), dtype=object)
    rest = np.isnan(outer_width)
    if len(levels) and fill_distance >= levels[-1]:
        # nothing lies deeper inside an island than its innermost wall level reaches:
        # where that is empty (thin struts, small pins) so is the domain
        rest &= ~shapely.is_empty(walls[:, -1])
    fill[rest] = inset(islands[rest], fill_distance, _QUAD_SEGS)
    return outer_width, fill, loops.wall_loops(walls, wall_order)


def widen_thin_walls(
    islands: np.ndarray, walls: np.ndarray, w: float
) -> tuple[np.ndarray, np.ndarray]:
    """Widen the outer wall of thin islands so it fills the island (see the module doc).

    ``islands`` (p,) Polygons; ``walls`` (p, P) the wall levels from
    ``buffer(island, -c_k)`` with ``P >= 2``; ``w`` the line width, mm. The
    rings of an island shorten by ``k`` mm per mm of inset (``2 pi`` for each
    exterior of a round island, less for each hole), measured between the
    outline and the outer level (length ``L_0``, area ``A_0``); an inset by ``r``
    then takes ``L r - k r^2 / 2`` of area. An island is thin when the outer
    wall's ``w``-wide beads leave some area uncovered (``R = A_0 - L_0 w / 2 +
    k w^2 / 8 > 0``) and the second level's beads with all they enclose
    (``A_1 + L_1 w / 2 + pi w^2 / 4`` per part, 0 when empty) would cover under
    :data:`THIN_SECOND` of it (empty, or specks where the island is thickest).
    Its outer wall is then the level ``c_0 = W / 2`` extruded ``W`` wide, ``W``
    the width whose beads lay the island's area ``A``: ``W L(W/2) = A`` with
    ``L(c) = L_0 - k (c - w/2)``, when ``w < W <= THIN_MAX w``; its other levels
    are dropped. An island thinner than two lines, whose outer beads overlap
    (``R < 0``) and which has no second level, gets the same narrowed to
    ``THIN_MIN w <= W < w``, so the two sides of its ring lay its area instead
    of up to twice it. Returns the walls (a copy when changed) and the outer wall
    width per island (p,) mm, NaN where it stays ``w``.
    """
    width = np.full(len(islands), np.nan)
    if len(islands) == 0 or walls.shape[1] < 2:
        return walls, width
    area = shapely.area(islands)
    a1 = shapely.area(walls[:, 1])
    # the second level covers at least its own area A_1 and R < A: A_1 < THIN_SECOND A is needed
    cand = np.flatnonzero((a1 < THIN_SECOND * area) & ~shapely.is_empty(walls[:, 0]))
    if len(cand) == 0:
        return walls, width
    first, second_level = walls[cand, 0], walls[cand, 1]
    l0 = shapely.length(first)
    # how fast the rings shorten per mm of inset (2 pi per exterior of a round island)
    k = (shapely.length(islands[cand]) - l0) / (w / 2.0)
    # beyond the outer wall's beads, and what the second level's beads and all inside cover
    beyond = shapely.area(first) - w / 2.0 * l0 + k * w * w / 8.0
    parts = np.where(shapely.is_empty(second_level), 0, shapely.get_num_geometries(second_level))
    second = a1[cand] + w / 2.0 * shapely.length(second_level) + parts * np.pi * w * w / 4.0
    thin = (beyond > 0) & (second < THIN_SECOND * beyond)
    # thinner than two lines: the outer beads overlap (R < 0) and there is no second level
    overlap = (beyond < 0) & (second == 0)
    pick = thin | overlap
    cand, l0, k, overlap = cand[pick], l0[pick], k[pick], overlap[pick]
    if len(cand) == 0:
        return walls, width
    # W L(W/2) = A with L(c) = L_0 - k (c - w/2): a W^2 - b W + A = 0, a = k / 2,
    # b = L_0 + k w / 2; the root near A / L_0, in a form that holds at k = 0
    a = k / 2.0
    b = l0 + a * w
    root = np.sqrt(np.maximum(b * b - 4.0 * a * area[cand], 0.0))
    wide = 2.0 * area[cand] / (b + root)
    grow = np.where(overlap, (wide >= THIN_MIN * w) & (wide < w),
                    (wide > w) & (wide <= THIN_MAX * w))
    cand, wide = cand[grow], wide[grow]
    if len(cand) == 0:
        return walls, width
    walls = walls.copy()
    walls[cand, 0] = inset(islands[cand], wide / 2.0, _QUAD_SEGS)
    walls[cand, 1:] = shapely.Polygon()
    width[cand] = wide
    return walls, width
