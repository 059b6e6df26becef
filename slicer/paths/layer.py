"""One layer's toolpaths: walls, skins, infill and support, ordered for printing.

Walls are level sets of the signed distance to the outline at
``c_k = w/2, 3w/2, ...``: on the exact vector route an inward offset of the
outline *is* that level set, so each wall is the boundary of
``buffer(outline, -c_k)`` (exterior and interior rings alike). Infill is the
level sets of the selected field, clipped to the contracted domain ``w'``.

Thin islands: where an island is nowhere thick enough for a second wall but
thicker than two lines (the second level would cover under a quarter of what
the outer wall's beads leave: empty, or specks), two lines of width ``w`` would
leave a strip unfilled between the two sides of the outer wall, which nothing
else can fill. Its outer wall is then the level set ``c_0 = W / 2``, extruded
``W`` wide, ``W`` the width whose beads lay the island's area (at most 1.375 w),
so the two sides meet about the medial axis (as the variable-width walls of
PrusaSlicer 2.5 and Cura 5 lay two wider lines there). Walls and domains are
made per island by :mod:`slicer.paths.islands`, once for an island that repeats.

Hatched solid fill lays no more than its region's area: in a region a few
lines across (a thin tower's corners), chords and the joints between them
would lay up to twice the area, so the run's width is cut to lay it exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from slicer.fields.base import InfillField, LayerContext
from slicer.fields.linear import LinearField, hatch_many, line_frame
from slicer.geometry import geom
from slicer.paths import loops, order, skinfill
from slicer.paths.islands import island_geometry
from slicer.settings import SliceSettings

WALL_OUTER = loops.WALL_OUTER
WALL_INNER = loops.WALL_INNER
SKIN = "SKIN"
FILL = "FILL"
SUPPORT = "SUPPORT"

# slicer.paths.support.support_paths: (support region, part outline, context, interface region or
# None) -> support paths by kind ("wall", "interface", "infill")
SupportPaths = Callable[
    [shapely.Geometry, shapely.Geometry, LayerContext, shapely.Geometry | None],
    dict[str, shapely.Geometry],
]
# paths shorter than this fraction of the line width are not printed
_MIN_PATH = 0.5


_POLYGON_ID = 3  # shapely.get_type_id of a Polygon


@dataclass(frozen=True)
class Path:
    """One extruded path: ``kind`` (a ``;TYPE:`` name) and ``coords`` (k, 2) float64 mm.

    Closed loops repeat their first point at the end. ``width`` is the line
    width in mm when it is not the settings' ``line_width`` (None: that).
    ``island`` is the index of the layer's island (``LayerRegions.islands``) the
    path lies in, -1 for none (support).
    """

    kind: str
    coords: np.ndarray
    width: float | None = None
    island: int = -1


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

    ``support_paths`` is :func:`slicer.paths.support.support_paths` when support is
    enabled (imported lazily by the plan), else None.
    """
    return layer_paths_many([(regions, ctx)], field, support_paths)[0]


def layer_paths_many(
    layers: list[tuple[LayerRegions, LayerContext]],
    field: InfillField,
    support_paths: SupportPaths | None = None,
) -> list[list[Path]]:
    """:func:`layer_paths` of every layer (``(regions, context)``, one settings for all),
    the same paths as one by one: the walls and domains of all their islands are made
    in one pass (:func:`slicer.paths.islands.island_geometry`), their chords are hatched and
    stacked a line direction at a time (:func:`_stacks_many`), and the joints of all
    their infill runs are checked in one pass (:func:`slicer.paths.order.join_runs`)."""
    out: list[list[Path]] = [[] for _ in layers]
    busy = [j for j, (regions, _) in enumerate(layers) if len(regions.islands)]
    for j, (regions, ctx) in enumerate(layers):
        support = _support_region(regions)
        if not len(regions.islands) and support_paths is not None and support is not None:
            b = support.bounds
            out[j] = _support(regions, ctx, support_paths, np.array([b[0], b[3]]))
    if not busy:
        return out
    settings = layers[busy[0]][1].settings
    w = settings.line_width
    sizes = [len(layers[j][0].islands) for j in busy]
    first_island = np.cumsum([0, *sizes]).tolist()
    outer_width, fill, rings = island_geometry(
        np.concatenate([layers[j][0].islands for j in busy]), w, settings.perimeters,
        fill_distance(settings), settings.wall_order,
    )
    spans = list(zip(busy, first_island[:-1], first_island[1:], strict=True))
    fills = [_fill_regions(layers[j][0], layers[j][1], fill[a:b]) for j, a, b in spans]
    # every layer's skin and sparse chords, hatched and stacked a line direction at a time
    shortest = _MIN_PATH * w
    asks = [_stack_asks(ctx_fill, layers[j][1], field) for (j, _, _), ctx_fill in
            zip(spans, fills, strict=True)]
    stacked = _stacks_many([ask for layer_asks in asks for ask in layer_asks], shortest)
    planned = []
    at = 0
    for (j, a, b), layer_fill, layer_asks in zip(spans, fills, asks, strict=True):
        answered = stacked[at : at + len(layer_asks)]
        at += len(layer_asks)
        planned.append(_planned_layer(layers[j][0], layers[j][1], field, outer_width[a:b],
                                      rings[a:b], layer_fill, answered))
    # every layer's runs joined at once: each run keeps to its own island's domain
    runs = [(pts, ends, first_island[slot] + k)
            for slot, plan in enumerate(planned) for pts, ends, k in plan.runs]
    laid = np.zeros(len(runs))
    joined = order.join_runs(runs, fill, 2.0 * w, w / 2.0, laid)
    done = 0
    for j, plan in zip(busy, planned, strict=True):
        count = len(plan.runs)
        mine = joined[done : done + count]
        widths = _capped_widths(laid[done : done + count], plan.runs, plan.hatched_skin,
                                plan.skin, w)
        done += count
        paths: list[Path] = []
        for item in plan.items:
            if isinstance(item, Path):
                paths.append(item)
            else:
                width = widths.get(item[1])
                island = plan.runs[item[1]][2]
                paths.extend(Path(item[0], coords, width, island) for coords in mine[item[1]])
        regions, ctx = layers[j]
        if support_paths is not None and _support_region(regions) is not None:
            paths.extend(_support(regions, ctx, support_paths, plan.pos))
        out[j] = paths
    return out


def _support_region(regions: LayerRegions) -> shapely.Geometry | None:
    """The layer's support region to fill, None when it has none."""
    support = regions.support
    return support if support is not None and not support.is_empty else None


@dataclass
class _PlannedLayer:
    """A layer's walls and infill runs in print order, before the runs' joints:
    ``items`` walls (:class:`Path`) and runs by kind (``(kind, run)``), ``runs``
    ``(points, ends, island)``, the runs of hatched skin, each island's skin and the
    nozzle's last position."""

    items: list[Path | tuple[str, int]]
    runs: list[tuple[np.ndarray, np.ndarray, int]]
    hatched_skin: list[int]
    skin: np.ndarray
    pos: np.ndarray


@dataclass
class _FillRegions:
    """A layer's infill regions per island: solid ``skin``, ``sparse``, and the skin
    laid along its length (``skin_lines``, per island)."""

    skin: np.ndarray
    sparse: np.ndarray
    skin_lines: list[list[np.ndarray]]


def _fill_regions(regions: LayerRegions, ctx: LayerContext, fill: np.ndarray) -> _FillRegions:
    """The skin and sparse regions of a layer's islands (infill domains ``fill``)."""
    settings = ctx.settings
    w = settings.line_width
    islands = regions.islands
    if regions.skin is not None and not regions.skin.is_empty:
        skin = _skin_by_island(fill, regions.skin)
        sparse = geom.difference(fill, regions.skin)
    else:
        skin = np.full(len(islands), None, dtype=object)
        sparse = fill
    skin, sparse = _solid_small_regions(skin, sparse, settings.infill_solid_below_area)
    skin_lines: list[list[np.ndarray]] = [[] for _ in range(len(islands))]
    if skinfill.wanted(settings):
        narrow, skin = skinfill.split_narrow(skin, w)
        skin_lines, skin = skinfill.along(narrow, skin, fill, w)
    return _FillRegions(skin, sparse, skin_lines)


# what a layer asks to be hatched and stacked: (groups of (regions, spacing), angle, layer)
_StackAsk = tuple[list[tuple[np.ndarray, float]], float, int]


def _stack_asks(regions: _FillRegions, ctx: LayerContext, field: InfillField) -> list[_StackAsk]:
    """The stacks a layer needs: its skin's and, with the linear field, its sparse
    infill's (one ask when both run one way: the same field, two spacings)."""
    settings = ctx.settings
    w = settings.line_width
    if isinstance(field, LinearField) and field.angle == settings.infill_angle:
        return [([(regions.skin, w), (regions.sparse, sparse_spacing(settings))],
                 field.angle, ctx.index)]
    asks = [([(regions.skin, w)], settings.infill_angle, ctx.index)]
    if isinstance(field, LinearField):
        asks.append(([(regions.sparse, sparse_spacing(settings))], field.angle, ctx.index))
    return asks


def _planned_layer(
    regions: LayerRegions, ctx: LayerContext, field: InfillField, outer_width: np.ndarray,
    rings: list[Any], fills: _FillRegions,
    stacked: list[list[tuple[order.ChordStacks, int] | None]],
) -> _PlannedLayer:
    """One layer's walls and infill runs (:class:`_PlannedLayer`) from its islands'
    walls, infill regions and the stacks it asked for (:func:`_stack_asks`)."""
    islands = regions.islands
    skin, sparse, skin_lines = fills.skin, fills.sparse, fills.skin_lines
    sparse_lines: list[list[np.ndarray]] = [[] for _ in range(len(islands))]
    if len(stacked) == 1 and len(stacked[0]) == 2:  # skin and sparse in one ask
        skin_stacks, sparse_stacks = stacked[0]
    else:
        (skin_stacks,) = stacked[0]
        if isinstance(field, LinearField):
            (sparse_stacks,) = stacked[1]
        else:
            sparse_stacks = None
            sparse_lines = _sparse_lines(sparse, ctx, field)

    # walls are final; infill runs are joined for all islands at once after the walk
    items: list[Path | tuple[str, int]] = []
    runs: list[tuple[np.ndarray, np.ndarray, int]] = []
    hatched_skin: list[int] = []  # the runs of skin chords (capped by their region's area)
    box = shapely.bounds(islands)
    pos = _start_position(box)
    for k in _island_order(box, pos):
        width = None if np.isnan(outer_width[k]) else float(outer_width[k])
        for kind, ring in loops.order_loops(rings[k], pos):
            items.append(Path(kind, ring, width if kind == WALL_OUTER else None, k))
            pos = ring[-1]
        if skin_lines[k]:  # narrow skin, along its length
            ordered, pos = order.order_open_paths(skin_lines[k], pos)
            items.append((SKIN, len(runs)))
            runs.append((np.concatenate(ordered), np.cumsum([len(c) for c in ordered]), k))
        for kind, kind_stacks in ((SKIN, skin_stacks), (FILL, sparse_stacks)):
            if kind_stacks is not None:
                stacks, first_group = kind_stacks
                block, pos = order.walk_stacks(stacks, first_group + k, pos)
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
            if kind == SKIN and kind_stacks is not None:
                hatched_skin.append(len(runs))
            items.append((kind, len(runs)))
            runs.append((pts, ends, k))
    return _PlannedLayer(items, runs, hatched_skin, skin, pos)


def _skin_by_island(fill: np.ndarray, skin: shapely.Geometry) -> np.ndarray:
    """The layer's ``skin`` (not empty) shared out to its islands' infill domains ``fill``
    (p,): (p,) the skin parts in each, as one MultiPolygon, or None.

    The skin lies in the layer's infill domain already (it is that domain, as the
    skins are found on it, less the cover), and the islands' domains lie apart, so
    each part of it lies in one of them: the one holding a point of the part.
    Sharing the parts out so takes no overlay of the domains with the skin.
    A part in none of them (a sliver of the skins' coarser domain outside the
    islands' own) is dropped, as an overlay would all but drop it.
    """
    if len(fill) == 1:
        return np.array([skin], dtype=object)
    parts = shapely.get_parts(skin)
    parts = parts[shapely.get_type_id(parts) == _POLYGON_ID]
    if len(parts) == 0:
        return np.full(len(fill), None, dtype=object)
    inside = shapely.point_on_surface(parts)
    part, island = shapely.STRtree(fill).query(inside, predicate="intersects")
    order = np.lexsort((part, island))
    return _grouped(parts[part[order]], island[order], np.arange(len(fill)))


def _capped_widths(
    laid: np.ndarray,
    runs: list[tuple[np.ndarray, np.ndarray, int]],
    capped: list[int],
    regions: np.ndarray,
    w: float,
) -> dict[int, float]:
    """Line width of the runs ``capped`` whose lines would lay more than their region holds.

    ``laid`` (len(runs),) the length of each run's joined paths, mm; ``runs``
    their ``(points, ends, island)``; ``regions`` (p,) the region each island's
    run fills (the solid region, inside the infill domain, so already reaching
    ``infill.overlap`` into the walls). A run whose lines, ``w`` mm wide, cover
    more than that area (chords and their joints in a region a few lines
    across: a thin tower's corners) gets the width that lays the region's area
    exactly; the others keep ``w`` (absent from the result).
    """
    if not capped:
        return {}
    area = shapely.area(regions[[runs[r][2] for r in capped]])
    length = laid[capped]
    over = (length * w > area) & (area > 0)  # False for NaN (no region)
    return {
        int(r): float(a / ell)
        for r, a, ell in zip(np.asarray(capped)[over], area[over], length[over], strict=True)
    }


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
    polygon = shapely.get_type_id(parts) == _POLYGON_ID
    parts, owner = parts[polygon], owner[polygon]
    if len(parts) == 0:
        return skin, sparse
    small = shapely.area(parts) < below
    if not small.any():
        return skin, sparse
    skin = skin.copy()
    sparse = sparse.copy()
    touched = geom.sorted_unique(owner[small])
    # each touched island's skin: its own parts, then its small sparse parts, in order
    # (disjoint pieces: the small ones come from fill - skin, so no overlay is needed)
    base_parts, base_owner = shapely.get_parts(skin[touched], return_index=True)
    of_touched = np.isin(owner, touched)
    moved = of_touched & small
    pieces = np.concatenate([base_parts, parts[moved]])
    piece_owner = np.concatenate([touched[base_owner], owner[moved]])
    polygons = shapely.get_type_id(pieces) == _POLYGON_ID
    pieces, piece_owner = pieces[polygons], piece_owner[polygons]
    by_island = np.argsort(piece_owner, kind="stable")
    skin[touched] = _grouped(pieces[by_island], piece_owner[by_island], touched)
    # and its sparse parts left (None when all were small)
    kept = of_touched & ~small
    sparse[touched] = _grouped(parts[kept], owner[kept], touched)
    return skin, sparse


def _grouped(pieces: np.ndarray, owner: np.ndarray, islands: np.ndarray) -> np.ndarray:
    """One MultiPolygon per island of ``islands`` (sorted) of the ``pieces`` it owns
    (``owner`` sorted, each in ``islands``), None for an island owning none."""
    out = np.full(len(islands), None, dtype=object)
    if len(pieces):
        present = geom.sorted_unique(owner)
        at = np.searchsorted(islands, present)
        out[at] = shapely.multipolygons(pieces, indices=np.searchsorted(present, owner))
    return out


def _start_position(box: np.ndarray) -> np.ndarray:
    """Where ordering starts: the rear-left corner of the layer (a fixed, layer-local point).

    ``box`` (p, 4) the islands' bounds (xmin, ymin, xmax, ymax), mm; NaN (empty) ignored.
    """
    return np.array([np.fmin.reduce(box[:, 0]), np.fmax.reduce(box[:, 3])])


# islands up to this many are ordered from one table of distances (its memory grows
# as the square: thousands of islands a layer walk the list instead)
_TABLE_ISLANDS = 256


def _island_order(box: np.ndarray, pos: np.ndarray) -> list[int]:
    """Islands in greedy nearest-neighbour order of their rear seams (``box`` (p, 4) their
    bounds)."""
    if len(box) == 1:
        return [0]
    b = box
    seams = np.stack([(b[:, 0] + b[:, 2]) / 2.0, b[:, 3]], axis=1)
    out = []
    if len(box) <= _TABLE_ISLANDS:
        # every seam's distance from the start and from every seam, at once (the same
        # numbers as one norm per step); a visited seam is ruled out by an infinite one
        table = np.linalg.norm(seams[None, :, :] - seams[:, None, :], axis=2)
        d = geom.lengths(seams - pos)
        for _ in range(len(box)):
            j = int(np.argmin(d))
            out.append(j)
            table[:, j] = np.inf
            d = table[j]
        return out
    left = list(range(len(box)))
    here = pos
    while left:
        d = geom.lengths(seams[left] - here)
        j = left.pop(int(np.argmin(d)))
        out.append(j)
        here = seams[j]
    return out


def _stacks_many(
    asks: list[_StackAsk], min_length: float
) -> list[list[tuple[order.ChordStacks, int] | None]]:
    """Level sets of the linear field (Eq. 13, mirrored on odd layers) in every region,
    stacked: for each ask ``(groups, angle, layer)`` (:func:`_stack_asks`), one entry
    per group of ``(regions, spacing)`` (``regions`` (p,) one (Multi)Polygon or None
    per island, lines ``spacing`` mm apart).

    The asks of one line direction (angle and parity) are hatched and stacked in one
    pass, every region its own group of stacks, so a region's stacks are those of a
    pass of its own. Chords shorter than ``min_length`` mm are dropped. Per group,
    the stacks and the stacks' group of its first island (island ``k``'s chords are
    group ``first + k``, :func:`slicer.paths.order.walk_stacks`); None where it has no
    chords at all.
    """
    out: list[list[tuple[order.ChordStacks, int] | None]] = [
        [None] * len(groups) for groups, _, _ in asks]
    ways: dict[tuple[float, bool], list[tuple[int, int]]] = {}  # direction -> (ask, group)
    for a, (groups, angle, index) in enumerate(asks):
        for j, (regions, spacing) in enumerate(groups):
            if spacing > 0 and len(regions):
                ways.setdefault((angle, index % 2 == 1), []).append((a, j))
    for (angle, mirror), todo in ways.items():
        regions_of = [asks[a][0][j][0] for a, j in todo]
        sizes = [len(r) for r in regions_of]
        regions = np.concatenate(regions_of)
        spacings = np.repeat([float(asks[a][0][j][1]) for a, j in todo], sizes)
        chords, owner = hatch_many(regions, angle, mirror, spacings)
        keep = geom.lengths(chords[:, 1] - chords[:, 0]) >= min_length
        if not keep.any():
            continue
        chords, owner = chords[keep], owner[keep]
        g, d = line_frame(angle, mirror)
        # every region its own group of stacks: one pass for all the groups' islands
        stacks = order.chord_stacks(chords, owner, len(regions), g, d, spacings[owner])
        offsets = np.cumsum([0, *sizes])
        has = np.bincount(owner, minlength=len(regions))
        for (a, j), lo, hi in zip(todo, offsets[:-1].tolist(), offsets[1:].tolist(),
                                  strict=True):
            if has[lo:hi].any():
                out[a][j] = (stacks, lo)
    return out


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
    return geom.split_rows(coords, cuts) if len(coords) else []


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
