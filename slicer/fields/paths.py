"""Toolpath finishing shared by the fields: clip to the region, keep contours apart, tidy."""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from slicer.geometry import geom

LINESTRING = 1


def prepared(geom: shapely.Geometry) -> shapely.Geometry:
    """``geom`` ready for fast repeated predicates, without touching the caller's object.

    A geometry the caller already prepared is used as is; otherwise a private copy
    is prepared, so threads slicing layers never prepare a shared object at once.
    """
    if shapely.is_prepared(geom):
        return geom
    copy = shapely.from_wkb(shapely.to_wkb(geom))
    shapely.prepare(copy)
    return copy


def empty_paths() -> shapely.Geometry:
    """An empty MultiLineString, the result of a field with nothing to fill."""
    return shapely.MultiLineString()


def as_multiline(lines: np.ndarray) -> shapely.Geometry:
    """Combine an array of LineStrings into one MultiLineString (empty if none)."""
    lines = np.asarray(lines, dtype=object)
    if lines.size == 0:
        return empty_paths()
    return shapely.multilinestrings(lines)


def linestring_parts(geoms: np.ndarray | shapely.Geometry) -> np.ndarray:
    """Every non-empty LineString inside ``geoms`` (any mix of line geometries), as an array."""
    parts: np.ndarray = shapely.get_parts(np.atleast_1d(np.asarray(geoms, dtype=object)))
    if parts.size == 0:
        return parts
    keep: NDArray[np.bool_] = (shapely.get_type_id(parts) == LINESTRING) & (
        shapely.length(parts) > 0.0
    )
    return parts[keep]


def clip(lines: np.ndarray, region: shapely.Geometry) -> np.ndarray:
    """Clip LineStrings to ``region`` in one vectorised call; returns the LineString pieces."""
    lines = np.asarray(lines, dtype=object)
    if lines.size == 0 or region.is_empty:
        return np.empty(0, dtype=object)
    region = prepared(region)
    hits = shapely.intersects(region, lines)
    return linestring_parts(_merged(geom.intersection(lines[hits], region)))


def split_runs(coords: np.ndarray, owner: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Rebuild LineStrings from the kept vertices, cutting wherever a vertex was dropped.

    ``coords`` (n, 2) float64 mm, ``owner`` (n,) int index of the line each vertex
    belongs to (grouped, in order), ``keep`` (n,) bool. Runs of fewer than two
    vertices vanish. Returns an array of LineStrings.
    """
    if coords.shape[0] == 0:
        return np.empty(0, dtype=object)
    prev_keep = np.concatenate(([False], keep[:-1]))
    new_owner = np.concatenate(([True], owner[1:] != owner[:-1]))
    starts = keep & (~prev_keep | new_owner)
    run = np.cumsum(starts) - 1
    run_kept = run[keep]
    counts = np.bincount(run_kept)
    valid = counts[run_kept] >= 2
    if not valid.any():
        return np.empty(0, dtype=object)
    runs, index = np.unique(run_kept[valid], return_inverse=True)
    pieces = shapely.linestrings(coords[keep][valid], indices=index)
    # a closed ring cut somewhere keeps its start vertex in two runs: join them again
    run_owner = owner[keep][valid][np.searchsorted(run_kept[valid], runs)]
    grouped = shapely.multilinestrings(pieces, indices=np.unique(run_owner, return_inverse=True)[1])
    return linestring_parts(shapely.line_merge(grouped))


def declutter(
    lines: np.ndarray,
    min_gap: float,
    priority: np.ndarray | None = None,
    tolerance: float | None = None,
) -> np.ndarray:
    """Cut lines where distinct lines (or far-apart stretches of one) come within ``min_gap``.

    Points are sampled every ``min_gap / 4`` mm; of each pair of points closer than
    ``min_gap`` that lie on different lines, the one on the line of lower
    ``priority`` (then the later line) is dropped; on the same line, a pair farther
    apart along the line than ``pi * min_gap`` (a hairpin) drops its later point.
    ``priority`` is (len(lines),) float, higher survives. Returns LineStrings,
    unchanged when nothing crowds; rebuilt lines are simplified by ``tolerance``.
    """
    lines = np.asarray(lines, dtype=object)
    if lines.size == 0 or min_gap <= 0:
        return lines
    dense = shapely.segmentize(lines, min_gap / 4.0)
    coords, owner = shapely.get_coordinates(dense, return_index=True)
    steps = np.linalg.norm(np.diff(coords, axis=0), axis=1)
    steps[owner[1:] != owner[:-1]] = 0.0
    arc = np.concatenate(([0.0], np.cumsum(steps)))
    arc -= arc[np.searchsorted(owner, owner)]  # distance along its own line
    pairs = cKDTree(coords).query_pairs(min_gap * (1.0 - 1e-9), output_type="ndarray")
    if pairs.shape[0] == 0:
        return lines
    a, b = pairs[:, 0], pairs[:, 1]
    la, lb = owner[a], owner[b]
    rank = np.zeros(lines.size) if priority is None else np.asarray(priority, dtype=float)
    same = la == lb
    along = np.abs(arc[a] - arc[b])
    closed = shapely.is_closed(lines)
    total = shapely.length(dense)
    along = np.where(closed[la], np.minimum(along, total[la] - along), along)
    hairpin = same & (along > np.pi * min_gap)
    distinct = ~same
    if not (hairpin.any() or distinct.any()):
        return lines
    a_wins = (rank[la] > rank[lb]) | ((rank[la] == rank[lb]) & (la < lb))
    loser = np.where(a_wins, b, a)[distinct]
    later = np.where(arc[a] > arc[b], a, b)[hairpin]
    dropped = np.zeros(coords.shape[0], dtype=bool)
    dropped[loser] = True
    dropped[later] = True
    keep = ~_widen(dropped, owner, arc, 0.5 * min_gap)
    rebuilt = split_runs(coords, owner, keep)
    if tolerance:
        rebuilt = shapely.simplify(rebuilt, tolerance)
    return rebuilt


def finish(
    lines: np.ndarray,
    region: shapely.Geometry,
    line_width: float,
    priority: np.ndarray | None = None,
) -> shapely.Geometry:
    """Clip ``lines`` to ``region``, keep distinct paths one line width apart, drop crumbs.

    ``priority`` (len(lines),) float decides which of two crowding lines keeps its
    stretch (higher wins). Pieces shorter than two line widths are dropped.
    Returns a MultiLineString (possibly empty).
    """
    lines = np.asarray(lines, dtype=object)
    if lines.size == 0:
        return empty_paths()
    region = prepared(region)
    if priority is not None:
        pieces = _merged(geom.intersection(lines, region))
        parts, source = shapely.get_parts(pieces, return_index=True)
        keep = (shapely.get_type_id(parts) == LINESTRING) & (shapely.length(parts) > 0.0)
        clipped, priority = parts[keep], np.asarray(priority, dtype=float)[source[keep]]
    else:
        clipped = clip(lines, region)
    tidy = declutter(clipped, line_width, priority)
    tidy = clip(shapely.simplify(tidy, line_width / 40.0), region)  # chords may cut corners
    tidy = tidy[shapely.length(tidy) >= 2.0 * line_width] if tidy.size else tidy
    return as_multiline(tidy)


def _widen(
    dropped: NDArray[np.bool_], owner: np.ndarray, arc: np.ndarray, reach: float
) -> NDArray[np.bool_]:
    """Also drop every vertex within ``reach`` mm along its line of a dropped one, so the
    two ends left at a cut lie apart rather than facing each other across a crumb gap."""
    if not dropped.any():
        return dropped
    key = owner * (float(arc.max()) + 4.0 * reach) + arc
    cut = key[dropped]  # sorted: owner and arc both increase along the arrays
    pos = np.searchsorted(cut, key)
    after = np.abs(cut[np.minimum(pos, cut.size - 1)] - key)
    before = np.abs(key - cut[np.maximum(pos - 1, 0)])
    near: NDArray[np.bool_] = np.minimum(after, before) <= reach
    return dropped | near


def _merged(pieces: np.ndarray) -> np.ndarray:
    """Join the pieces of each clipped line that meet end to end (a ring cut at its start)."""
    multi = shapely.get_type_id(pieces) == 5
    out = np.array(pieces, dtype=object)
    if multi.any():
        out[multi] = shapely.line_merge(pieces[multi])
    return out
