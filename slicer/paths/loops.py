"""Wall loops of every island of a layer, taken out of the wall polygons at once, and their order.

The rings of all islands and wall levels come out of shapely in one pass
(``get_parts`` / ``get_rings`` / ``get_coordinates`` over the whole (islands,
levels) array), and the rear seam of every ring is found with one sort; only
the greedy nearest-ring walk, which depends on where the nozzle is, runs per
island and level.
"""

from __future__ import annotations

import numpy as np
import shapely

from slicer.geometry.geom import split_rows
from slicer.paths import order

WALL_OUTER = "WALL-OUTER"
WALL_INNER = "WALL-INNER"


def wall_loops(
    walls: np.ndarray, wall_order: str
) -> list[list[tuple[str, list[np.ndarray], list[int]]]]:
    """Rings of each island's wall levels, in the wall order the settings ask for.

    ``walls`` (p, P) object array of (Multi)Polygons or None, level 0 the
    outer wall. Per island, a list of ``(kind, rings, seams)``: ``rings`` the
    closed rings of one level as (k, 2) float64 mm point arrays without the
    repeated closing point (exteriors counter-clockwise, holes clockwise;
    rings of fewer than 3 points dropped) and ``seams`` the index of each
    ring's rear seam vertex (:func:`slicer.paths.order.rear_seam`).
    """
    p, levels = walls.shape
    # per island: (kind, rings, seams, level) while the rings are gathered
    out: list[list[tuple[str, list[np.ndarray], list[int], int]]] = [[] for _ in range(p)]
    if p == 0 or levels == 0:
        return [[] for _ in range(p)]
    flat = shapely.orient_polygons(walls.ravel())
    parts, cell = shapely.get_parts(flat, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    coords, ring = shapely.get_coordinates(rings, return_index=True)
    if len(coords) == 0:
        return [[] for _ in range(p)]
    # drop each ring's repeated closing point
    size = np.bincount(ring, minlength=len(rings))
    start = np.cumsum(size) - size
    first = coords[start[ring]]
    last_of_ring = np.arange(len(coords)) == (start + size - 1)[ring]
    closing = last_of_ring & (size[ring] > 1) & (coords == first).all(axis=1)
    keep = ~closing
    coords, ring = coords[keep], ring[keep]
    size = np.bincount(ring, minlength=len(rings))
    start = np.cumsum(size) - size
    # rear seam of every ring: the rearmost (max y to 1 um), then leftmost point
    y = np.round(coords[:, 1], 3)
    best = np.lexsort((coords[:, 0], -y, ring))
    sorted_ring = ring[best]
    head = best[np.concatenate(([True], sorted_ring[1:] != sorted_ring[:-1]))]
    seam = np.zeros(len(rings), dtype=np.int64)
    seam[ring[head]] = head - start[ring[head]]
    pieces = split_rows(coords, start[1:])
    ring_cell = cell[ring_part].tolist()  # plain ints: numpy scalars are slow to index
    seams = seam.tolist()
    for r in np.flatnonzero(size >= 3).tolist():
        island, level = divmod(ring_cell[r], levels)
        loops = out[island]
        if not loops or loops[-1][3] != level:
            loops.append((WALL_OUTER if level == 0 else WALL_INNER, [], [], level))
        loops[-1][1].append(pieces[r])
        loops[-1][2].append(seams[r])
    result = []
    for loops in out:
        levels_of = [(kind, rings_, seams) for kind, rings_, seams, _ in loops]
        if wall_order == "inner_first":
            levels_of.reverse()
        result.append(levels_of)
    return result


def order_loops(
    levels: list[tuple[str, list[np.ndarray], list[int]]], pos: np.ndarray
) -> list[tuple[str, np.ndarray]]:
    """Closed loops level by level, nearest first; outer walls seam at the rear.

    ``levels`` one island's entry of :func:`wall_loops`; ``pos`` (2,) mm where
    the nozzle is. Returns ``(kind, ring)`` with each ring closed, (k + 1, 2).
    """
    out = []
    here = np.asarray(pos, dtype=np.float64)
    for kind, rings, seams in levels:
        outer = kind == WALL_OUTER
        if len(rings) == 1:
            pts = rings[0]
            start = seams[0] if outer else order.nearest_vertex(pts, here)
            ring = order.start_ring_at(pts, start)
            out.append((kind, ring))
            here = ring[-1]
            continue
        pts_x, pts_y = np.concatenate(rings).T
        sizes = np.array([len(r) for r in rings])
        starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        done = np.zeros(len(rings), dtype=bool)
        for _ in range(len(rings)):
            dx, dy = pts_x - here[0], pts_y - here[1]
            dist = np.minimum.reduceat(dx * dx + dy * dy, starts)
            dist[done] = np.inf
            j = int(dist.argmin())
            done[j] = True
            pts = rings[j]
            start = seams[j] if outer else order.nearest_vertex(pts, here)
            ring = order.start_ring_at(pts, start)
            out.append((kind, ring))
            here = ring[-1]
    return out
