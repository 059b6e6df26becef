"""Top and bottom skin regions of every layer, from the layer outlines alone.

Layer ``i`` needs solid skin where its infill domain ``F_i`` (inside the walls)
is not covered by the infill domain of *every* one of the ``top_layers``
layers above it, or of the ``bottom_layers`` layers below (the bed and empty
layers count as air). Comparing with the neighbours' infill domains rather
than their outlines also makes the shell of sloped surfaces solid: where the
walls of nearby layers pass over this layer's infill, there is solid fill, so
the outer surface is closed and as thick as the walls whatever the sparse
field (PrusaSlicer's "ensure vertical shell thickness"). A part of a skin
narrower than ``2 _OPEN`` (one 0.4 mm line) everywhere, one that an inward
offset by ``_OPEN`` empties, is left to the walls and the sparse infill, as
PrusaSlicer leaves it: on steep slopes the cover misses only a hair-thin band
behind the walls, which hatched solid was many short chords over-extruding
into them (1.10-1.19 times PrusaSlicer's filament on a sphere and a cone).

With the window intersections ``W(j, k) = F_j ∩ ... ∩ F_{j+k-1}``, the cover
from above is ``U_i = W(i+1, top)``, the cover from below ``D_i = W(i-bottom,
bottom)``, and the skin ``(F_i - U_i) ∪ (F_i - D_i) = F_i - (U_i ∩ D_i)``: one
difference per layer and no union. When ``top == bottom = k`` the windows are
shared, ``D_i = U_{i-k-1}``, so a layer costs at most one window (``k - 1``
intersections), one intersection ``U_i ∩ D_i`` and one difference, against
``2 (k - 1)`` intersections, two differences and a union when each side is
found apart.
Windows are cached by their first layer and size, whatever block asks for
them, and so are the infill domains; both are forgotten once every block that
uses them is solved. Bitwise-equal domains (prismatic parts; recognised by
their outlines' WKB) take part in a window once, so a window of equal layers
costs nothing; when one window's distinct domains are among the other's, the
cover is the window with more of them, as it is; a layer covered by domains
equal to its own alone has no skin, without any overlay.

Every result is a function of the outlines of the layer and its neighbours
alone (a window's domains are intersected in the order of its layers), so a
layer's skin is the same bitwise whatever block computes it. Where
neighbours share edges with ``F_i`` the overlays can leave hair-thin slivers
in ``F_i`` minus the cover; parts thinner on average than ``_SLIVER`` (a
fortieth of a 0.4 mm line) are dropped. The domains are simplified by plain
Douglas-Peucker, the topology-preserving kind only where that lost a part or
a hole. Everything runs as shapely array operations over the layers of a
block at once.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Protocol

import numpy as np
import shapely

from slicer.geometry import geom

# largest deviation of the domains used to find skins, mm
_SIMPLIFY = 0.1
# skin parts narrower than twice this everywhere are dropped, mm
_OPEN = 0.2
# skin parts thinner than this on average (2 area / perimeter) are overlay noise, mm
_SLIVER = 0.01
# a layer's skin smaller than this is none, mm^2
_MIN_AREA = 1e-6
# label of a layer that is air (beyond the model's ends, or empty)
_AIR = -1
# a domain not made yet
_MISSING = object()


def _labels(geoms: np.ndarray) -> np.ndarray:
    """Equal numbers for bitwise-equal geometries (same WKB), (n,) int64; None is its own."""
    seen: dict[bytes, int] = {}
    wkb = shapely.to_wkb(geoms)
    return np.array([seen.setdefault(w if w is not None else b"", len(seen)) for w in wkb],
                    dtype=np.int64)


def _domains(
    outlines: np.ndarray, fill_distance: float,
    inward: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Infill domains used to find skins, (n,) object array: each outline of ``outlines``
    (n,) buffered inward by ``fill_distance`` (or ``inward(outlines)``, the layers' own
    infill domains) and simplified by ``_SIMPLIFY``.

    Skins need no finer detail than this, and it halves the overlays' work on
    curved parts. Plain Douglas-Peucker is several times faster than the
    topology-preserving kind; the latter is used only where the former lost
    a part or a hole, or made an invalid polygon.
    """
    if inward is None:
        fill = shapely.buffer(outlines, -fill_distance, quad_segs=6)
    else:
        fill = inward(outlines)
    fast: np.ndarray = shapely.simplify(fill, _SIMPLIFY, preserve_topology=False)
    lost = (_rings(fast) != _rings(fill)) | ~shapely.is_valid(fast)
    if lost.any():
        fast[lost] = shapely.simplify(fill[lost], _SIMPLIFY)
    return fast


def _rings(polygons: np.ndarray) -> np.ndarray:
    """Number of rings (shells and holes) of each (Multi)Polygon of ``polygons`` (n,),
    (n,) int64; 0 for None or empty."""
    parts, owner = shapely.get_parts(polygons, return_index=True)
    per_part = shapely.get_num_interior_rings(parts) + 1
    return np.bincount(owner, weights=per_part, minlength=len(polygons)).astype(np.int64)


def _distinct(labels: np.ndarray) -> tuple[int, ...]:
    """The distinct labels of a window (k,) in order of first appearance; () when a
    layer of the window is air."""
    if (labels == _AIR).any():
        return ()
    return tuple(dict.fromkeys(labels.tolist()))


def _fold(fill: np.ndarray, windows: list[tuple[int, ...]]) -> np.ndarray:
    """Intersection of each window's domains, (len(windows),) object array.

    ``fill`` (m,) the distinct domains by label; each window a non-empty tuple
    of distinct labels, intersected left to right (the layers' order), all
    windows one step at a time.
    """
    out = np.array([fill[w[0]] for w in windows], dtype=object)
    sizes = np.array([len(w) for w in windows], dtype=np.int64)
    for step in range(1, int(sizes.max(initial=1))):
        rows = np.flatnonzero(sizes > step)
        other = np.array([fill[windows[r][step]] for r in rows], dtype=object)
        out[rows] = geom.intersection(out[rows], other)
    return out


def _drop_slivers(regions: np.ndarray) -> np.ndarray:
    """``regions`` (m,) without their sliver parts (and lines or points), (m,) object array;
    None where nothing is left. Regions that lose nothing are returned as they are."""
    out = regions.copy()
    parts, owner = shapely.get_parts(regions, return_index=True)
    if len(parts) == 0:
        return np.full(len(regions), None, dtype=object)
    area = shapely.area(parts)
    keep = 2.0 * area > _SLIVER * shapely.length(parts)
    kept = np.bincount(owner[keep], minlength=len(regions))
    total = np.bincount(owner, minlength=len(regions))
    changed = np.flatnonzero(kept < total)
    out[changed] = None
    mask = keep & np.isin(owner, changed)
    if mask.any():
        left = parts[mask]
        rows, first, inverse, count = np.unique(
            owner[mask], return_index=True, return_inverse=True, return_counts=True
        )
        multi = shapely.multipolygons(left, indices=inverse)
        single = count == 1
        out[rows[single]] = left[first[single]]
        out[rows[~single]] = multi[~single]
    area_left = shapely.area(out)
    out[~(area_left > _MIN_AREA)] = None
    return out


def _narrow_dropped(regions: np.ndarray) -> np.ndarray:
    """``regions`` (m,) without their parts narrower than ``2 _OPEN`` everywhere, (m,)
    object array (None where nothing is left): the parts that an inward offset by
    ``_OPEN`` empties."""
    out = regions.copy()
    rows = np.flatnonzero([g is not None for g in regions])
    if len(rows) == 0:
        return out
    parts, owner = shapely.get_parts(regions[rows], return_index=True)
    if len(parts) == 0:
        return out
    wide = ~shapely.is_empty(shapely.buffer(parts, -_OPEN, quad_segs=2))
    kept = np.bincount(owner[wide], minlength=len(rows))
    total = np.bincount(owner, minlength=len(rows))
    changed = np.flatnonzero(kept < total)
    for r in changed:
        mine = parts[(owner == r) & wide]
        out[rows[r]] = (
            None if len(mine) == 0 else mine[0] if len(mine) == 1 else shapely.multipolygons(mine)
        )
    return out


class LayerOutlines(Protocol):
    """Layer outlines by index: an object array of MultiPolygons, or a LazyOutlines."""

    def __len__(self) -> int: ...

    def __getitem__(self, key: slice, /) -> np.ndarray | shapely.Geometry: ...


class SkinCache:
    """Skin regions computed on demand in blocks of layers, each block once, thread-safe.

    A layer's skin needs its neighbours, so skins are made for ``block``
    layers at a time (vectorised), when the first of them is asked for;
    threads slicing different blocks compute them in parallel. The first
    ``block`` layers come in growing blocks (layers 0, 1, 2-3, 4-7, 8-15 for
    16): the first layer with something to print, the one the printer waits
    for, needs only its few neighbours' outlines and skins. A layer's skin is
    the same whatever block it is computed in.

    Infill domains and window intersections are kept for the blocks around
    (they are never prepared, so threads may share them); two threads making
    the same one at once make the same geometry. A layer's infill domain is
    its outline buffered in by ``fill_distance``, or ``inward(outlines)`` when
    given: the plan passes its islands' own domains, whose walls are then made
    in the same pass and kept for the layers' toolpaths.
    """

    def __init__(
        self, outlines: LayerOutlines, fill_distance: float, top: int, bottom: int, block: int = 16,
        inward: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self._outlines = outlines
        self._fill_distance = fill_distance
        self._inward = inward
        self._top = max(int(top), 0)
        self._bottom = max(int(bottom), 0)
        self._block = block
        self._lock = threading.Lock()
        self._blocks: dict[int, np.ndarray] = {}
        self._busy: dict[int, threading.Lock] = {}
        self._fill: dict[int, shapely.Geometry | None] = {}  # layer -> infill domain
        self._cover: dict[tuple[int, int], shapely.Geometry] = {}  # (first, size) -> W
        self._forgotten: set[int] = set()  # blocks solved, then let go (forget_before)

    def _span(self, i: int) -> tuple[int, int, int]:
        """(key, lo, hi): the block holding layer ``i``, layers ``lo..hi-1``."""
        first = 1 << (i.bit_length() - 1) if i > 0 else 0  # the growing blocks' first layer
        key = -1 - first if i < self._block else i // self._block
        return (key, *self._block_layers(key))

    def _block_layers(self, key: int) -> tuple[int, int]:
        """(lo, hi): the layers ``lo..hi-1`` of the block :meth:`_span` calls ``key``."""
        if key < 0:
            lo = -1 - key
            hi = min(max(2 * lo, 1), self._block)
        else:
            lo, hi = key * self._block, key * self._block + self._block
        return lo, min(hi, len(self._outlines))

    def get(self, i: int) -> shapely.Geometry | None:
        """Skin region of layer ``i`` (None when the layer needs no skin)."""
        b, lo, hi = self._span(int(i))
        with self._lock:
            done = self._blocks.get(b)
            if done is not None:
                return done[i - lo]
            busy = self._busy.setdefault(b, threading.Lock())
        with busy:
            with self._lock:
                done = self._blocks.get(b)
            if done is None:
                done = self.solve(lo, hi)
                with self._lock:
                    self._blocks[b] = done
                    self._prune()
        return done[i - lo]

    def _prune(self) -> None:
        """Forget the domains and windows that no block left to solve needs (lock held)."""
        n = len(self._outlines)
        top, bottom = self._top, self._bottom
        # open[j]: layers 0..j-1 that belong to a block not solved yet
        unsolved = np.ones(n, dtype=bool)
        for block in (*self._blocks, *self._forgotten):
            lo, hi = self._block_layers(block)
            unsolved[lo:hi] = False
        open_ = np.concatenate(([0], np.cumsum(unsolved)))

        def needed(first: int, last: int) -> bool:
            """Whether a layer in ``first..last`` belongs to a block not solved yet."""
            first, last = max(first, 0), min(last, n - 1)
            return first <= last and bool(open_[last + 1] > open_[first])

        for j in [j for j in self._fill if not needed(j - top, j + bottom)]:
            del self._fill[j]
        for key in [k for k in self._cover if not needed(*self._users(*k))]:
            del self._cover[key]

    def forget_before(self, layer: int) -> int:
        """Let go of the skins of the blocks all of whose layers lie below ``layer``; a
        layer of them asked for again is solved again, the same. Returns how many."""
        with self._lock:
            gone = [b for b in self._blocks if self._block_layers(b)[1] <= layer]
            for b in gone:
                del self._blocks[b]
                self._busy.pop(b, None)
                self._forgotten.add(b)
        return len(gone)

    @property
    def held_blocks(self) -> int:
        """Blocks of skins held now."""
        with self._lock:
            return len(self._blocks)

    def _users(self, first: int, size: int) -> tuple[int, int]:
        """The first and last layer whose skin uses the window ``W(first, size)``."""
        users = [first - 1] if size == self._top else []
        if size == self._bottom:
            users.append(first + self._bottom)
        return min(users), max(users)

    def solve(self, lo: int, hi: int) -> np.ndarray:
        """Skin regions of layers ``lo..hi-1``: (hi - lo,) object array of (Multi)Polygons
        or None, each inside its layer's infill domain (not kept by the cache)."""
        n = len(self._outlines)
        top, bottom = self._top, self._bottom
        if hi <= lo or (top == 0 and bottom == 0):
            return np.full(max(hi - lo, 0), None, dtype=object)
        # a neighbour outside [a, b) lies beyond the model's ends, and is air
        a, b = max(0, lo - bottom), min(n, hi + top)
        window = np.asarray(self._outlines[a:b], dtype=object)
        same = _labels(window)
        fill = self._distinct_domains(window, same, a)
        live = ~shapely.is_empty(fill) & np.array([f is not None for f in fill], dtype=bool)
        same = np.where(live[same], same, _AIR)
        targets = np.arange(lo, hi)
        # a layer's skin depends on its own domain and those of its neighbours alone:
        # layers with the same stack of labels have the same skin
        pad = np.concatenate((np.full(bottom, _AIR), same, np.full(top, _AIR)))
        at = targets - a + bottom
        stacks = np.stack([pad[at + k] for k in range(-bottom, top + 1)], axis=1)
        _, rep, back = np.unique(stacks, axis=0, return_index=True, return_inverse=True)
        out = self._skins(fill, stacks[rep], targets[rep])
        return out[back.reshape(-1)]

    def _distinct_domains(self, window: np.ndarray, same: np.ndarray, a: int) -> np.ndarray:
        """Infill domain by label, (same.max() + 1,) object array, for the outlines
        ``window`` (w,) of layers ``a..`` labelled ``same`` (w,); each made once
        per model (kept by layer) and once per block (equal outlines)."""
        first = np.unique(same, return_index=True)[1]
        with self._lock:
            known = [self._fill.get(a + int(f), _MISSING) for f in first]
        fill = np.empty(len(first), dtype=object)
        fill[:] = known
        todo = np.array([k is _MISSING for k in known], dtype=bool)
        if todo.any():
            fill[todo] = _domains(window[first[todo]], self._fill_distance, self._inward)
        with self._lock:
            for label, layer in enumerate(first):
                self._fill.setdefault(a + int(layer), fill[label])
        return fill

    def _windows(
        self, fill: np.ndarray, stacks: np.ndarray, targets: np.ndarray, size: int, offset: int
    ) -> tuple[np.ndarray, list[tuple[int, ...]]]:
        """The window intersection ``W(i + offset, size)`` of each target ``i``.

        ``fill`` (m,) domains by label; ``stacks`` (t, bottom + 1 + top) the
        labels of each target's layers ``i - bottom .. i + top``; ``targets``
        (t,) layer numbers. Returns (t,) object array (None where the window
        holds air) and each window's distinct labels (() for air).
        """
        at = self._bottom + offset
        labels = [_distinct(row) for row in stacks[:, at : at + size]]
        covers = np.full(len(targets), None, dtype=object)
        keys = [(int(i) + offset, size) for i in targets]
        with self._lock:
            known = [self._cover.get(k) for k in keys]
        todo: dict[tuple[int, ...], list[int]] = {}
        for r, (got, lab) in enumerate(zip(known, labels, strict=True)):
            if got is not None:
                covers[r] = got
            elif lab:
                todo.setdefault(lab, []).append(r)
        if todo:
            made = _fold(fill, list(todo))
            for cover, rows in zip(made, todo.values(), strict=True):
                covers[rows] = cover
            with self._lock:
                for rows in todo.values():
                    for r in rows:
                        self._cover.setdefault(keys[r], covers[r])
        return covers, labels

    def _skins(self, fill: np.ndarray, stacks: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Skin of each target ``F_i - (U_i ∩ D_i)``, (t,) object array or None.

        ``fill`` (m,) domains by label; ``stacks`` (t, bottom + 1 + top) the
        labels of the layers ``i - bottom .. i + top`` of each target ``i``
        of ``targets`` (t,).
        """
        top, bottom = self._top, self._bottom
        own = stacks[:, bottom]
        here = np.array([fill[k] if k != _AIR else None for k in own], dtype=object)
        out = np.full(len(targets), None, dtype=object)
        live = own != _AIR
        air = np.zeros(len(targets), dtype=bool)  # a covering window holds air: all is skin
        sides: list[tuple[np.ndarray, list[frozenset[int]]]] = []
        for size, offset in ((top, 1), (bottom, -bottom)):
            if size == 0:
                continue
            covers, labels = self._windows(fill, stacks, targets, size, offset)
            air |= np.array([not lab for lab in labels], dtype=bool)
            sides.append((covers, [frozenset(lab) for lab in labels]))
        out[live & air] = here[live & air]
        todo = np.flatnonzero(live & ~air)
        # solve() asks for no skins at all when both counts are 0
        cover = _meet(sides[0], sides[1], todo) if len(sides) == 2 else sides[0][0]
        # covered by domains equal to its own alone: no skin
        sets = [frozenset().union(*(side[1][r] for side in sides)) for r in todo]
        solid = np.array([s != {int(own[r])} for s, r in zip(sets, todo, strict=True)], dtype=bool)
        todo = todo[solid]
        if len(todo):
            out[todo] = _narrow_dropped(_drop_slivers(geom.difference(here[todo], cover[todo])))
        small = np.array([g is not None and not g.area > _MIN_AREA for g in out], dtype=bool)
        out[small] = None
        return out


def _meet(
    up: tuple[np.ndarray, list[frozenset[int]]],
    down: tuple[np.ndarray, list[frozenset[int]]],
    rows: np.ndarray,
) -> np.ndarray:
    """``U ∩ D`` at ``rows`` of the covers from above and below, (t,) object array.

    ``up`` and ``down`` are each (covers (t,), distinct labels of each
    window); when one window's domains are among the other's, the cover is
    the window with more domains, as it is.
    """
    (u, u_set), (d, d_set) = up, down
    cover = u.copy()
    need = np.zeros(len(u), dtype=bool)
    for r in rows:
        if d_set[r] <= u_set[r]:  # U ⊆ D
            continue
        if u_set[r] <= d_set[r]:
            cover[r] = d[r]
        else:
            need[r] = True
    if need.any():
        cover[need] = geom.intersection(u[need], d[need])
    return cover


def skin_regions(outlines: np.ndarray, fill_distance: float, top: int, bottom: int) -> np.ndarray:
    """Skin region of every layer, (n,) object array of (Multi)Polygons or None, for the
    layers' outlines ``outlines`` (n,), bottom layer first; ``fill_distance`` mm
    from the outline to the infill domain, ``top`` and ``bottom`` the numbers of
    solid layers (one block spanning the model)."""
    outlines = np.asarray(outlines, dtype=object)
    return SkinCache(outlines, fill_distance, top, bottom).solve(0, len(outlines))
