"""Robust wrappers of shapely overlays: retry on a fixed precision grid when GEOS gives up."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import TypeAlias

import numpy as np
import shapely
from shapely.errors import GEOSException

# grid that overlays fall back to when exact floating point fails, mm
GRID = 1e-6

# a shapely geometry, or an object array of them (shapely itself carries no type information)
Shapes: TypeAlias = shapely.Geometry | np.ndarray


def overlay(op: Callable[..., Shapes], a: Shapes, b: Shapes) -> Shapes:
    """``op(a, b)`` (a shapely set operation, arrays broadcast); element by element on a
    precision grid where GEOS raises a topology error."""
    try:
        return op(a, b)
    except GEOSException:
        pass
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_arr, b_arr = np.broadcast_arrays(np.asarray(a, dtype=object), np.asarray(b, dtype=object))
        out = np.empty(a_arr.shape, dtype=object)
        for idx in np.ndindex(a_arr.shape):
            out[idx] = overlay(op, a_arr[idx], b_arr[idx])
        return out
    return op(_on_grid(a), _on_grid(b), grid_size=GRID)


def _on_grid(g: shapely.Geometry) -> shapely.Geometry:
    """``g`` valid on the precision grid; an invalid ``g`` (parts of a region that
    cross, from a degenerate mesh) is made valid first, as the grid alone cannot."""
    try:
        return shapely.make_valid(shapely.set_precision(g, GRID))
    except GEOSException:
        return shapely.make_valid(shapely.set_precision(shapely.make_valid(g), GRID))


def intersection(a: Shapes, b: Shapes) -> Shapes:
    """Robust ``shapely.intersection``."""
    return overlay(shapely.intersection, a, b)


def difference(a: Shapes, b: Shapes) -> Shapes:
    """Robust ``shapely.difference``."""
    return overlay(shapely.difference, a, b)


def union(a: Shapes, b: Shapes) -> Shapes:
    """Robust ``shapely.union``."""
    return overlay(shapely.union, a, b)


def polygonal(geom: shapely.Geometry) -> shapely.Geometry:
    """The polygonal part of a geometry (overlays can return lines and points too)."""
    if geom is None:
        return shapely.MultiPolygon()
    if geom.geom_type in ("Polygon", "MultiPolygon"):
        return geom
    parts = [g for g in shapely.get_parts(geom) if g.geom_type in ("Polygon", "MultiPolygon")]
    if not parts:
        return shapely.MultiPolygon()
    return shapely.union_all(parts)


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """``np.unique(a)`` of a flat array without NaN: its distinct values, sorted, same dtype.

    By sort and compare: ``np.unique`` itself imports ``numpy.ma`` on its first call
    (numpy 2.3 on), a tenth of the start-up of a small slice.
    """
    s = np.sort(a, axis=None)
    if len(s) < 2:
        return s
    keep = np.empty(len(s), dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def split_rows(a: np.ndarray, cuts: np.ndarray | list[int]) -> list[np.ndarray]:
    """``np.split(a, cuts)``: the views ``a[0:c0], a[c0:c1], ..., a[ck:]``, by plain
    slicing (``np.split`` swaps axes twice per piece, which cost more than the pieces
    on a layer's hundreds of paths)."""
    bounds = [0, *np.asarray(cuts).tolist(), len(a)]
    return [a[lo:hi] for lo, hi in itertools.pairwise(bounds)]


def private_copy(g: shapely.Geometry) -> shapely.Geometry:
    """A copy of ``g`` (same coordinates, exactly) that one thread may prepare: GEOS
    prepared geometries build their indexes lazily and must not be shared across
    threads. A clone with its XY coordinates copied in, about 10x quicker than a
    round trip through WKB. (Z is dropped: the slicer's regions are flat.)"""
    return shapely.transform(g, _same)


def _same(xy: np.ndarray) -> np.ndarray:
    return xy


def lengths(v: np.ndarray) -> np.ndarray:
    """Lengths of vectors ``v`` (n, 2): ``np.linalg.norm(v, axis=1)`` to the bit (the same
    squares, one sum and a square root), without its generic checks (a few calls a layer
    on short arrays, where they cost more than the arithmetic)."""
    x, y = v[:, 0], v[:, 1]
    out: np.ndarray = np.sqrt(x * x + y * y)
    return out
