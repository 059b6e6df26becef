"""One layer's toolpaths: walls, skins, infill and support, ordered for printing.

Walls are level sets of the signed distance to the outline at
``c_k = w/2, 3w/2, ...``: on the exact vector route an inward offset of the
outline *is* that level set, so each wall is the boundary of
``buffer(outline, -c_k)`` (exterior and interior rings alike). Infill is the
level sets of the selected field, clipped to the contracted domain ``w'``.

Thin islands: where an island is nowhere thick enough for a second wall but
thicker than two lines (maximum inscribed radius ``h`` with ``w < h <=
THIN_WIDEN w``), two lines of width ``w`` would leave a strip of ``2h - 2w``
unfilled between the two sides of the outer wall, which nothing else can fill.
Its outer wall is then the level set ``c_0 = h / 2``, extruded ``h`` wide, so the
two sides meet on the medial axis (as the variable-width walls of PrusaSlicer
2.5 and Cura 5 lay two wider lines there).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely

from slicer import geom, loops, order, skinfill
from slicer.fields.base import InfillField, LayerContext
from slicer.fields.linear import LinearField, hatch_many, line_frame
from slicer.settings import SliceSettings

WALL_OUTER = loops.WALL_OUTER
WALL_INNER = loops.WALL_INNER
SKIN = "SKIN"
FILL = "FILL"
SUPPORT = "SUPPORT"

# arcs of offset corners: segments per quarter circle
_QUAD_SEGS = 6
# slicer.support.support_paths: (support region, part outline, context, interface region or
# None) -> support paths by kind ("wall", "interface", "infill")
SupportPaths = Callable[
    [shapely.Geometry, shapely.Geometry, LayerContext, shapely.Geometry | None],
    dict[str, shapely.Geometry],
]
# paths shorter than this fraction of the line width are not printed
_MIN_PATH = 0.5
# thin islands up to this inscribed radius (in line widths) get one widened outer
# wall instead of two lines with a gap between them (Arachne's 2-to-3-line step)
THIN_WIDEN = 1.375
# bisection steps for a thin island's inscribed radius (to w/32: 0.0125 mm at w = 0.4)
_THIN_STEPS = 4


@dataclass(frozen=True)
class Path:
    """One extruded path: ``kind`` (a ``;TYPE:`` name) and ``coords`` (k, 2) float64 mm.

    Closed loops repeat their first point at the end. ``width`` is the line
    width in mm when it is not the settings' ``line_width`` (None: that).
    """

    kind: str
    coords: np.ndarray
    width: float | None = None


@dataclass(frozen=True)
class LayerRegions:
    """The regions one layer is made of (bed coordinates, mm).

    ``islands`` (p,) Polygons, the layer's solid region per connected part;
    ``skin`` where solid skin is needed, inside the infill domain (None or
    empty when nowhere); ``support`` the
    support region and ``interface`` its part just under the part (or None).
    """

    islands: np.ndarray
    skin: shapely.Geometry
    support: shapely.Geometry | None = None
    interface: shapely.Geometry | None = None


def fill_distance(settings: SliceSettings) -> float:
    """Distance from the outline to the edge of the infill domain w', mm.

    With ``P`` walls of width ``w`` the innermost wall's inner edge is at
    ``P w``; infill lines reach ``infill.overlap * w`` into that wall so they
    bond. Without walls the infill's bead edge lies on the outline.
    """
    w = settings.line_width
    p = settings.perimeters
    if p == 0:
        return w / 2.0
    return p * w - settings.infill_overlap * w


def sparse_spacing(settings: SliceSettings) -> float:
    """Mean distance between sparse infill lines for ``infill.density``, mm.

    Lines of width ``w`` every ``s`` mm extrude the volume fraction ``w / s``,
    so ``s = w / density`` makes the extruded fraction equal the density.
    """
    if settings.infill_density <= 0:
        return 0.0
    return settings.line_width / min(1.0, settings.infill_density)


def layer_paths(
    regions: LayerRegions,
    ctx: LayerContext,
    field: InfillField,
    support_paths: SupportPaths | None = None,
) -> list[Path]:
    """Every toolpath of one layer, in print order.

    ``support_paths`` is :func:`slicer.support.support_paths` when support is
    enabled (imported lazily by the plan), else None.
    """
    settings = ctx.settings
    islands = regions.islands
    support = regions.support
    has_support = support_paths is not None and support is not None and not support.is_empty
    if len(islands) == 0:
        if support_paths is None or support is None or support.is_empty:
            return []
        b = support.bounds
        return _support(regions, ctx, support_paths, np.array([b[0], b[3]]))
    w = settings.line_width
    levels = (np.arange(settings.perimeters) + 0.5) * w
    walls = (
        shapely.buffer(islands[:, None], -levels[None, :], quad_segs=_QUAD_SEGS)
        if len(levels)
        else np.empty((len(islands), 0), dtype=object)
    )
    outer_width = np.full(len(islands), np.nan)  # NaN: the settings' line width
    if settings.perimeters >= 2:
        walls, outer_width = widen_thin_walls(islands, walls, w)
    fill = shapely.buffer(islands, -fill_distance(settings), quad_segs=_QUAD_SEGS)
    if regions.skin is not None and not regions.skin.is_empty:
        if len(islands) == 1:  # the skin already lies in this island's infill domain
            skin = np.array([regions.skin], dtype=object)
        else:
            skin = geom.intersection(fill, regions.skin)
        sparse = geom.difference(fill, regions.skin)
    else:
        skin = np.full(len(islands), None, dtype=object)
        sparse = fill
    skin, sparse = _solid_small_regions(skin, sparse, settings.infill_solid_below_area)
    shortest = _MIN_PATH * w
    skin_lines: list[list[np.ndarray]] = [[] for _ in range(len(islands))]
    if skinfill.wanted(settings):
        narrow, skin = skinfill.split_narrow(skin, w)
        skin_lines, skin = skinfill.along(narrow, skin, fill, w)
    skin_stacks = _stacks(skin, settings.infill_angle, ctx.index, w, shortest)
    sparse_lines: list[list[np.ndarray]] = [[] for _ in range(len(islands))]
    if isinstance(field, LinearField):
        spacing = sparse_spacing(settings)
        sparse_stacks = _stacks(sparse, field.angle, ctx.index, spacing, shortest)
    else:
        sparse_stacks = None
        sparse_lines = _sparse_lines(sparse, ctx, field)
    rings = loops.wall_loops(walls, settings.wall_order)

    # walls are final; infill runs are joined for all islands at once after the walk
    items: list[Path | tuple[str, int]] = []
    runs: list[tuple[np.ndarray, np.ndarray, int]] = []
    pos = _start_position(islands)
    for k in _island_order(islands, pos):
        width = None if np.isnan(outer_width[k]) else float(outer_width[k])
        for kind, ring in loops.order_loops(rings[k], pos):
            items.append(Path(kind, ring, width if kind == WALL_OUTER else None))
            pos = ring[-1]
        if skin_lines[k]:  # narrow skin, along its length
            ordered, pos = order.order_open_paths(skin_lines[k], pos)
            items.append((SKIN, len(runs)))
            runs.append((np.concatenate(ordered), np.cumsum([len(c) for c in ordered]), k))
        for kind, stacks in ((SKIN, skin_stacks), (FILL, sparse_stacks)):
            if stacks is not None:
                block, pos = order.walk_stacks(stacks, k, pos)
                if len(block) == 0:
                    continue
                pts = block.reshape(-1, 2)
                ends = np.arange(2, len(pts) + 1, 2)
            elif kind == FILL and sparse_lines[k]:
                ordered, pos = order.order_open_paths(sparse_lines[k], pos)
                pts = np.concatenate(ordered)
                ends = np.cumsum([len(c) for c in ordered])
            else:
                continue
            items.append((kind, len(runs)))
            runs.append((pts, ends, k))
    joined = order.join_runs(runs, fill, 2.0 * w, w / 2.0)
    out: list[Path] = []
    for item in items:
        if isinstance(item, Path):
            out.append(item)
        else:
            out.extend(Path(item[0], coords) for coords in joined[item[1]])
    if support_paths is not None and has_support:
        out.extend(_support(regions, ctx, support_paths, pos))
    return out


def widen_thin_walls(
    islands: np.ndarray, walls: np.ndarray, w: float
) -> tuple[np.ndarray, np.ndarray]:
    """Widen the outer wall of thin islands so its two sides meet (see the module doc).

    ``islands`` (p,) Polygons; ``walls`` (p, P) the wall levels from
    ``buffer(island, -c_k)`` with ``P >= 2``; ``w`` the line width, mm. An island
    whose second wall is empty and whose maximum inscribed radius ``h`` lies in
    ``(w, THIN_WIDEN w]`` gets the outer wall level ``buffer(island, -h / 2)``.
    Returns the walls (a copy when changed) and the outer wall width per
    island (p,) mm, NaN where it stays ``w``.
    """
    width = np.full(len(islands), np.nan)
    if len(islands) == 0 or walls.shape[1] < 2:
        return walls, width
    # no second wall: h <= 1.5 w
    cand = np.flatnonzero(shapely.is_empty(walls[:, 1]) & ~shapely.is_empty(walls[:, 0]))
    if len(cand) == 0:
        return walls, width
    # the outer wall level is the island less w/2: h > w where it survives another w/2
    first = walls[cand, 0]
    keep = ~shapely.is_empty(shapely.buffer(first, -w / 2.0, quad_segs=_QUAD_SEGS))
    cand, first = cand[keep], first[keep]
    if len(cand) == 0:
        return walls, width
    # h - w/2 in (w/2, w] by bisection on where the level's inward offset empties
    lo = np.full(len(cand), w / 2.0)
    hi = np.full(len(cand), w)
    for _ in range(_THIN_STEPS):
        mid = (lo + hi) / 2.0
        empty = shapely.is_empty(shapely.buffer(first, -mid, quad_segs=_QUAD_SEGS))
        hi = np.where(empty, mid, hi)
        lo = np.where(empty, lo, mid)
    h = w / 2.0 + (lo + hi) / 2.0
    thin = h <= THIN_WIDEN * w
    if not thin.any():
        return walls, width
    cand, h = cand[thin], h[thin]
    walls = walls.copy()
    walls[cand, 0] = shapely.buffer(islands[cand], -h / 2.0, quad_segs=_QUAD_SEGS)
    width[cand] = h
    return walls, width


def _solid_small_regions(
    skin: np.ndarray, sparse: np.ndarray, below: float
) -> tuple[np.ndarray, np.ndarray]:
    """Move sparse regions smaller than ``below`` mm^2 into the skin, per island.

    Sparse lines in a small region are a few short strokes that add little
    strength and many travels; solid fill there is what PrusaSlicer does too
    (its ``solid_infill_below_area``).
    """
    if below <= 0:
        return skin, sparse
    parts, owner = shapely.get_parts(sparse, return_index=True)
    polygon = shapely.get_type_id(parts) == 3
    parts, owner = parts[polygon], owner[polygon]
    if len(parts) == 0:
        return skin, sparse
    small = shapely.area(parts) < below
    if not small.any():
        return skin, sparse
    skin = skin.copy()
    sparse = sparse.copy()
    for i in geom.sorted_unique(owner[small]):
        mine = owner == i
        solid = parts[mine & small]
        rest = parts[mine & ~small]
        base = skin[i]
        if base is not None and not base.is_empty:
            solid = np.concatenate([shapely.get_parts(base), solid])
        # disjoint pieces (the small ones come from fill - skin): no overlay needed
        solid = solid[shapely.get_type_id(solid) == 3]
        skin[i] = shapely.multipolygons(solid)
        sparse[i] = shapely.multipolygons(rest) if len(rest) else None
    return skin, sparse


def _start_position(islands: np.ndarray) -> np.ndarray:
    """Where ordering starts: the rear-left corner of the layer (a fixed, layer-local point)."""
    b = shapely.total_bounds(islands)
    return np.array([b[0], b[3]])


def _island_order(islands: np.ndarray, pos: np.ndarray) -> list[int]:
    """Islands in greedy nearest-neighbour order of their rear seams."""
    if len(islands) == 1:
        return [0]
    b = shapely.bounds(islands)
    seams = np.stack([(b[:, 0] + b[:, 2]) / 2.0, b[:, 3]], axis=1)
    left = list(range(len(islands)))
    out = []
    here = pos
    while left:
        d = np.linalg.norm(seams[left] - here, axis=1)
        j = left.pop(int(np.argmin(d)))
        out.append(j)
        here = seams[j]
    return out


def _stacks(
    regions: np.ndarray, angle: float, index: int, spacing: float, min_length: float
) -> order.ChordStacks | None:
    """Level sets of the linear field (Eq. 13, mirrored on odd layers) in every region, stacked.

    ``regions`` (p,) one (Multi)Polygon or None per island; chords shorter than
    ``min_length`` mm are dropped. None when there are no chords at all.
    """
    if spacing <= 0 or len(regions) == 0:
        return None
    mirror = index % 2 == 1
    chords, owner = hatch_many(regions, angle, mirror, spacing)
    if len(chords) == 0:
        return None
    length = np.linalg.norm(chords[:, 1] - chords[:, 0], axis=1)
    keep = length >= min_length
    if not keep.any():
        return None
    g, d = line_frame(angle, mirror)
    return order.chord_stacks(chords[keep], owner[keep], len(regions), g, d, spacing)


def _sparse_lines(
    sparse: np.ndarray, ctx: LayerContext, field: InfillField
) -> list[list[np.ndarray]]:
    """Sparse infill of every island from the field, split back per island."""
    spacing = sparse_spacing(ctx.settings)
    n = len(sparse)
    out: list[list[np.ndarray]] = [[] for _ in range(n)]
    if spacing <= 0:
        return out
    nonempty = [i for i in range(n) if sparse[i] is not None and not sparse[i].is_empty]
    if not nonempty:
        return out
    region = sparse[nonempty[0]] if len(nonempty) == 1 else shapely.union_all(sparse[nonempty])
    lines = field.paths(region, ctx, spacing)
    parts = shapely.get_parts(lines)
    if len(parts) == 0:
        return out
    if len(nonempty) == 1:
        out[nonempty[0]] = _as_coords(parts, ctx.settings.line_width)
        return out
    probe = shapely.get_point(parts, 0)
    tree = shapely.STRtree(sparse[nonempty])
    pi, ti = tree.query(probe, predicate="intersects")
    first = np.unique(pi, return_index=True)[1]
    owner = np.full(len(parts), -1)
    owner[pi[first]] = np.asarray(nonempty)[ti[first]]
    for i in nonempty:
        out[i] = _as_coords(parts[owner == i], ctx.settings.line_width)
    return out


def _as_coords(lines: shapely.Geometry | np.ndarray, w: float) -> list[np.ndarray]:
    """Point arrays of the line parts long enough to print."""
    parts = shapely.get_parts(lines)
    if len(parts) == 0:
        return []
    parts = parts[shapely.length(parts) >= _MIN_PATH * w]
    coords, index = shapely.get_coordinates(parts, return_index=True)
    cuts = np.flatnonzero(np.diff(index)) + 1
    return np.split(coords, cuts) if len(coords) else []


def _support(
    regions: LayerRegions, ctx: LayerContext, support_paths: SupportPaths, pos: np.ndarray
) -> list[Path]:
    """Support toolpaths (wall, interface and infill), nearest first."""
    outline = shapely.union_all(regions.islands) if len(regions.islands) else shapely.Polygon()
    parts = support_paths(regions.support, outline, ctx, regions.interface)
    out: list[Path] = []
    lines: list[np.ndarray] = []
    for key in ("wall", "interface", "infill"):
        geom = parts.get(key)
        if geom is not None and not geom.is_empty:
            lines.extend(_as_coords(geom, ctx.settings.line_width))
    ordered, _ = order.order_open_paths(lines, pos)
    out.extend(Path(SUPPORT, c) for c in ordered)
    return out
