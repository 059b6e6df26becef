"""Top and bottom skin regions of every layer, from the layer outlines alone.

Layer ``i`` needs solid skin where its infill domain ``F_i`` (inside the walls)
is not covered by the infill domain of *every* one of the ``top_layers``
layers above it, or of the ``bottom_layers`` layers below (the bed and empty
layers count as air). Comparing with the neighbours' infill domains rather
than their outlines also makes the shell of sloped surfaces solid: where the
walls of nearby layers pass over this layer's infill, there is solid fill, so
the outer surface is closed and as thick as the walls whatever the sparse
field (PrusaSlicer's "ensure vertical shell thickness").

Since ``F - (F_1 ∩ ... ∩ F_k) = F - ∩{F_j : F_j does not contain F}``, a
cheap vectorised ``contains`` test on prepared domains rules out most
neighbours, and overlays are computed only where a surface really is near.
Everything runs as shapely array operations over all layers at once.
"""

from __future__ import annotations

import threading

import numpy as np
import shapely

from slicer import geom

# largest deviation of the domains used to find skins, mm
_SIMPLIFY = 0.1


def _exposed(
    fill: np.ndarray, cover_by: np.ndarray, count: int, direction: int, targets: np.ndarray
) -> np.ndarray:
    """Part of the fill domain of each layer in ``targets`` not covered by all ``count``
    layers in ``direction`` (+1 up, -1 down); (len(targets),) object array.

    ``fill`` (n,) the layers' infill domains; ``cover_by`` (n,) what a
    neighbour covers with (prepared copies of the same domains); a neighbour
    beyond either end of the arrays is air.
    """
    n = len(fill)
    m = len(targets)
    result = np.full(m, None, dtype=object)
    if count <= 0 or m == 0:
        return result
    here = fill[targets]
    live = np.array([f is not None and not f.is_empty for f in here], dtype=bool)
    bare = np.zeros(m, dtype=bool)  # a neighbour is missing: the whole domain is skin
    cover = np.full(m, None, dtype=object)
    for k in range(1, count + 1):
        j = targets + direction * k
        inside_range = (j >= 0) & (j < n)
        other = np.full(m, None, dtype=object)
        other[inside_range] = cover_by[j[inside_range]]
        missing = np.array([o is None or o.is_empty for o in other], dtype=bool)
        bare |= missing & live
        todo = np.flatnonzero(live & ~bare)
        if len(todo) == 0:
            break
        covered = shapely.contains(other[todo], here[todo])
        todo = todo[~covered]
        if len(todo) == 0:
            continue
        first = np.array([cover[t] is None for t in todo], dtype=bool)
        cover[todo[first]] = other[todo[first]]
        rest = todo[~first]
        if len(rest):
            cover[rest] = geom.intersection(cover[rest], other[rest])
    result[bare] = here[bare]
    idx = np.flatnonzero(~bare & np.array([c is not None for c in cover], dtype=bool))
    if len(idx):
        result[idx] = geom.difference(here[idx], cover[idx])
    return result


def skin_block(
    outlines: np.ndarray, lo: int, hi: int, fill_distance: float, top: int, bottom: int
) -> np.ndarray:
    """Skin regions of layers ``lo..hi-1``: (hi - lo,) object array of (Multi)Polygons or None.

    ``outlines`` (n,) every layer's (Multi)Polygon, bottom layer first;
    ``fill_distance`` mm from the outline to the infill domain; ``top`` and
    ``bottom`` the numbers of solid layers. Only the layers of the block and
    their neighbours are buffered; the prepared copies it makes are its own,
    so blocks may run on several threads at once. The result lies inside each
    layer's infill domain.
    """
    n = len(outlines)
    if hi <= lo or (top <= 0 and bottom <= 0):
        return np.full(max(hi - lo, 0), None, dtype=object)
    a, b = max(0, lo - bottom), min(n, hi + top)
    # prismatic parts repeat outlines: each distinct outline of the window is
    # buffered once, and each distinct stack of neighbours solved once
    window = np.asarray(outlines[a:b], dtype=object)
    same = _labels(window)
    first = np.unique(same, return_index=True)[1]
    fill = shapely.buffer(window[first], -fill_distance, quad_segs=6)
    # skins need no finer detail than this; it halves the overlays' work on curved parts
    fill = shapely.simplify(fill, _SIMPLIFY)
    # predicates run on prepared copies private to this call: GEOS builds
    # prepared indexes lazily, so a prepared geometry must never be shared
    private = shapely.from_wkb(shapely.to_wkb(fill))
    shapely.prepare(private)
    fill, private = fill[same], private[same]
    targets = np.arange(lo - a, hi - a)
    # a layer's skin depends on its own domain and those of its neighbours alone
    pad = np.concatenate((np.full(bottom, -1), same, np.full(top, -1)))
    stacks = np.stack([pad[targets + bottom + k] for k in range(-bottom, top + 1)], axis=1)
    _, rep, back = np.unique(stacks, axis=0, return_index=True, return_inverse=True)
    targets = targets[rep]
    up = _exposed(fill, private, top, 1, targets)
    down = _exposed(fill, private, bottom, -1, targets)
    del private
    # a neighbour outside [a, b) lies beyond the model's ends only, which _exposed
    # treats as air; inside the model the window always reaches far enough
    has_a = np.array([g is not None and not g.is_empty for g in up], dtype=bool)
    has_b = np.array([g is not None and not g.is_empty for g in down], dtype=bool)
    out = np.full(len(targets), None, dtype=object)
    out[has_a] = up[has_a]
    out[has_b & ~has_a] = down[has_b & ~has_a]
    both = has_a & has_b
    if both.any():
        out[both] = geom.union(up[both], down[both])
    keep = np.array([g is not None and g.area > 1e-6 for g in out], dtype=bool)
    out[~keep] = None
    return out[back.reshape(-1)]


def _labels(geoms: np.ndarray) -> np.ndarray:
    """Equal numbers for bitwise-equal geometries (same WKB), (n,) int64; None is its own."""
    seen: dict[bytes, int] = {}
    wkb = shapely.to_wkb(geoms)
    return np.array([seen.setdefault(w if w is not None else b"", len(seen)) for w in wkb],
                    dtype=np.int64)


def skin_regions(outlines: np.ndarray, fill_distance: float, top: int, bottom: int) -> np.ndarray:
    """Skin region of every layer (one block spanning the model); see :func:`skin_block`."""
    outlines = np.asarray(outlines, dtype=object)
    return skin_block(outlines, 0, len(outlines), fill_distance, top, bottom)


class SkinCache:
    """Skin regions computed on demand in blocks of layers, each block once, thread-safe.

    A layer's skin needs its neighbours, so skins are made for ``block``
    layers at a time (vectorised), when the first of them is asked for;
    threads slicing different blocks compute them in parallel. The first
    ``block`` layers come in growing blocks (layers 0, 1, 2-3, 4-7, 8-15 for
    16): the first layer with something to print, the one the printer waits
    for, needs only its few neighbours' outlines and skins. A layer's skin is
    the same whatever block it is computed in.
    """

    def __init__(
        self, outlines: np.ndarray, fill_distance: float, top: int, bottom: int, block: int = 16
    ) -> None:
        self._outlines = outlines
        self._args = (fill_distance, top, bottom)
        self._block = block
        self._lock = threading.Lock()
        self._blocks: dict[int, np.ndarray] = {}
        self._busy: dict[int, threading.Lock] = {}

    def _span(self, i: int) -> tuple[int, int, int]:
        """(key, lo, hi): the block holding layer ``i``, layers ``lo..hi-1``."""
        if i < self._block:
            lo = 1 << (i.bit_length() - 1) if i > 0 else 0
            hi = min(max(2 * lo, 1), self._block)
            key = -1 - lo
        else:
            key = i // self._block
            lo, hi = key * self._block, key * self._block + self._block
        return key, lo, min(hi, len(self._outlines))

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
                done = skin_block(self._outlines, lo, hi, *self._args)
                with self._lock:
                    self._blocks[b] = done
        return done[i - lo]
