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

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import shapely

from slicer import geom


def _shifted(outlines: np.ndarray, step: int) -> np.ndarray:
    """``out[i] = outlines[i + step]``, None beyond either end."""
    n = len(outlines)
    out = np.full(n, None, dtype=object)
    if abs(step) >= n:
        return out
    if step > 0:
        out[: n - step] = outlines[step:]
    else:
        out[-step:] = outlines[: n + step]
    return out


def _exposed(fill: np.ndarray, cover_by: np.ndarray, count: int, direction: int) -> np.ndarray:
    """Part of each layer's fill domain not covered by all ``count`` layers in ``direction``.

    ``fill`` (n,) the layers' infill domains; ``cover_by`` (n,) what a
    neighbour covers with (prepared copies of the same domains).
    """
    outlines = cover_by
    n = len(outlines)
    result = np.full(n, None, dtype=object)
    if count <= 0:
        return result
    live = np.array([f is not None and not f.is_empty for f in fill], dtype=bool)
    bare = np.zeros(n, dtype=bool)  # a neighbour is missing: the whole domain is skin
    cover = np.full(n, None, dtype=object)
    for k in range(1, count + 1):
        other = _shifted(outlines, direction * k)
        missing = np.array([o is None or o.is_empty for o in other], dtype=bool)
        bare |= missing & live
        todo = np.flatnonzero(live & ~bare)
        if len(todo) == 0:
            break
        inside = shapely.contains(other[todo], fill[todo])
        todo = todo[~inside]
        if len(todo) == 0:
            continue
        first = np.array([cover[t] is None for t in todo], dtype=bool)
        cover[todo[first]] = other[todo[first]]
        rest = todo[~first]
        if len(rest):
            cover[rest] = geom.intersection(cover[rest], other[rest])
    result[bare] = fill[bare]
    idx = np.flatnonzero(~bare & np.array([c is not None for c in cover], dtype=bool))
    if len(idx):
        result[idx] = geom.difference(fill[idx], cover[idx])
    return result


def skin_regions(
    outlines: np.ndarray, fill_distance: float, top: int, bottom: int, threads: int = 2
) -> np.ndarray:
    """Skin region of every layer: (n,) object array of (Multi)Polygons, or None for no skin.

    ``outlines`` (n,) (Multi)Polygons, bottom layer first;
    ``fill_distance`` mm from the outline to the infill domain; ``top`` and
    ``bottom`` the numbers of solid layers. The result lies inside each
    layer's infill domain. Work is split over ``threads`` threads (shapely
    releases the interpreter lock).
    """
    outlines = np.asarray(outlines, dtype=object)
    n = len(outlines)
    if n == 0 or (top <= 0 and bottom <= 0):
        return np.full(n, None, dtype=object)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        halves = np.array_split(np.arange(n), threads)
        parts = pool.map(
            lambda idx: shapely.buffer(outlines[idx], -fill_distance, quad_segs=6), halves
        )
        fill = np.concatenate(list(parts))
    # predicates run on prepared copies, in this thread only: GEOS builds
    # prepared indexes lazily, so a prepared geometry must never be shared
    private = shapely.from_wkb(shapely.to_wkb(fill))
    shapely.prepare(private)
    a = _exposed(fill, private, top, 1)
    b = _exposed(fill, private, bottom, -1)
    del private
    has_a = np.array([g is not None and not g.is_empty for g in a], dtype=bool)
    has_b = np.array([g is not None and not g.is_empty for g in b], dtype=bool)
    out = np.full(n, None, dtype=object)
    out[has_a] = a[has_a]
    out[has_b & ~has_a] = b[has_b & ~has_a]
    both = has_a & has_b
    if both.any():
        out[both] = geom.union(a[both], b[both])
    keep = np.array([g is not None and g.area > 1e-6 for g in out], dtype=bool)
    out[~keep] = None
    return out
