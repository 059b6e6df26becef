"""Layer outlines: cut chains become shapely polygons with holes, per layer and per body.

Closed loops are nested by orientation and containment, vectorised across all layers
of a block at once (one STRtree over boxes shifted apart by layer, one
vectorised ``contains``). Open chains (open meshes) are joined end to start
when the gap is small and closed; layers whose polygons overlap (overlapping
shells, self-intersections) are made valid by a union per layer.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from slicer.geometry import geom
from slicer.input.section import Chains

# shortest ring worth keeping, mm^2 of area
_MIN_RING_AREA = 1e-4


@dataclass(frozen=True)
class OutlineTolerances:
    """Tolerances of the outline stage, mm.

    ``simplify``: largest deviation allowed when thinning cut loops;
    ``stitch_gap``: open chains whose ends are this close are joined first;
    ``max_gap``: an open chain left over is closed on itself across at most
    this gap (wider ones are dropped); ``hole_gap``: the widest gap across
    which a chain may close as a hole (clockwise).
    """

    simplify: float = 0.01
    stitch_gap: float = 2.0
    max_gap: float = 60.0
    hole_gap: float = 10.0


@dataclass
class GapReport:
    """What the outline stage had to fix, over all layers.

    ``closed``/``dropped``: gaps of open meshes bridged and chains left open;
    ``gap_layers``: layers where that happened; ``repaired_layers``: layers made
    valid by a union; ``merged``: pairs of bodies found overlapping.
    """

    closed: int = 0
    dropped: int = 0
    gap_layers: set[int] = field(default_factory=set)
    repaired_layers: set[int] = field(default_factory=set)
    merged: set[tuple[int, int]] = field(default_factory=set)


def close_open_chains(
    coords: list[np.ndarray], stitch_gap: float, max_gap: float, hole_gap: float | None = None
) -> tuple[list[np.ndarray], int, int]:
    """Close the open chains of one layer into loops, as CuraEngine does.

    ``coords``: open chains, each (k, 2) float64 mm, oriented with the solid
    on the left (so joining an end to a start keeps the orientation). First
    the globally closest end/start pairs within ``stitch_gap`` are joined (a
    chain's own start closes it); then every chain left is closed on itself
    when its ends are at most ``max_gap`` apart: an outer boundary closes
    counter-clockwise (solid), a pocket seen through the opening clockwise (a
    hole). A hole is only closed across at most ``hole_gap`` (default
    ``max_gap``): across a wider opening the mesh does not say where the hole
    ends, so the chain is dropped and the region stays solid, as PrusaSlicer
    and CuraEngine leave it (the bunny's open underside). Returns the loops,
    the number of gaps bridged and the number of chains dropped.
    """
    hole_gap = max_gap if hole_gap is None else hole_gap
    chains = [c for c in coords if len(c) >= 2]
    loops: list[np.ndarray] = []
    gaps = 0
    while chains:
        ends = np.array([c[-1] for c in chains])
        starts = np.array([c[0] for c in chains])
        dist = np.linalg.norm(ends[:, None, :] - starts[None, :, :], axis=2)
        i, j = np.unravel_index(int(np.argmin(dist)), dist.shape)
        if dist[i, j] > stitch_gap:
            break
        gaps += 1
        if i == j:
            loops.append(chains.pop(i))
            continue
        joined = np.concatenate([chains[i], chains[j]])
        for k in sorted((i, j), reverse=True):
            chains.pop(k)
        chains.append(joined)
    dropped = 0
    for c in chains:
        gap = np.linalg.norm(c[-1] - c[0]) if len(c) >= 3 else np.inf
        if gap <= max_gap and (gap <= hole_gap or _signed_area(c) > 0.0):
            loops.append(c)
            gaps += 1
        else:
            dropped += 1
    return loops, gaps, dropped


# a loop point this close (mm) to the line through its neighbours carries no shape
_COLLINEAR = 1e-7


def drop_collinear(coords: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Loops without their repeated points and points on the straight line between neighbours.

    ``coords`` (n, 2) float64 mm, loop after loop; ``offsets`` (k + 1,) int64.
    A flat wall modelled as long triangles is cut across their diagonals at
    heights that change from layer to layer; those points lie on the wall's
    straight edge, and dropping them gives equal layers equal loops (and the
    thinning that follows the same choices on every layer). Returns the kept
    coordinates and offsets (a loop may end with fewer than three points).
    """
    sizes = np.diff(offsets)
    n = len(coords)
    if n == 0:
        return coords, offsets
    ring = np.repeat(np.arange(len(sizes)), sizes)
    start = offsets[:-1][ring]
    size = sizes[ring]
    pos = np.arange(n) - start
    a = coords[start + (pos - 1) % size]
    c = coords[start + (pos + 1) % size]
    ab = coords - a
    bc = c - coords
    cross = np.abs(ab[:, 0] * bc[:, 1] - ab[:, 1] * bc[:, 0])
    span = np.hypot(c[:, 0] - a[:, 0], c[:, 1] - a[:, 1])
    repeated = (ab[:, 0] == 0) & (ab[:, 1] == 0)
    between = (cross <= _COLLINEAR * span) & ((ab * bc).sum(axis=1) > 0)
    keep = ~(repeated | between)
    if keep.all():
        return coords, offsets
    kept = np.bincount(ring[keep], minlength=len(sizes))
    return coords[keep], np.concatenate(([0], np.cumsum(kept))).astype(np.int64)


def _signed_area(ring: np.ndarray) -> float:
    """Shoelace area of a ring (k, 2) closed on itself: positive when counter-clockwise."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def build_layers(
    chains: Chains,
    face_body: np.ndarray,
    layer_ids: np.ndarray,
    tol: OutlineTolerances,
    report: GapReport,
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Polygons with holes for each layer of a block.

    ``chains`` from :func:`slicer.input.section.cut_block`; ``face_body`` (f,) int64,
    the body (connected shell) of each mesh face; ``layer_ids`` the layers of
    this block. Returns ``{layer: (polygons (p,) object, body (p,) int64)}``;
    a layer without polygons is absent.
    """
    coords, offsets, layer, face = _close_gaps(chains, tol, report)
    if len(layer) == 0:
        return {}
    coords, offsets = drop_collinear(coords, offsets)
    sizes = np.diff(offsets)
    # a loop of one or two points (a stray sheet's single segment closed on itself,
    # or a loop thinned to a line) encloses nothing and is no ring: left out before
    # the rings are built, which refuses fewer than three distinct points
    keep = sizes >= 3
    if not keep.all():
        coords = coords[np.repeat(keep, sizes)]
        sizes = sizes[keep]
        layer = layer[keep]
        face = face[keep]
    if len(sizes) == 0:
        return {}
    ring_idx = np.repeat(np.arange(len(sizes)), sizes)
    rings = shapely.linearrings(coords, indices=ring_idx)
    if tol.simplify > 0:
        rings = shapely.simplify(rings, tol.simplify, preserve_topology=False)
        ok = (shapely.get_type_id(rings) == 2) & (shapely.get_num_coordinates(rings) >= 4)
        rings, layer, face = rings[ok], layer[ok], face[ok]
    polys = shapely.polygons(rings)
    area = shapely.area(polys)
    ok = area > _MIN_RING_AREA
    rings, polys, layer, face, area = rings[ok], polys[ok], layer[ok], face[ok], area[ok]
    if len(rings) == 0:
        return {}
    body = face_body[face]
    exterior, parent = _nesting(polys, shapely.is_ccw(rings), layer, area)
    owner = np.where(exterior, np.arange(len(rings)), parent)
    valid = owner >= 0
    order = np.lexsort((np.nonzero(valid)[0], ~exterior[valid], owner[valid]))
    members = np.nonzero(valid)[0][order]
    groups, index = np.unique(owner[members], return_inverse=True)
    built = shapely.polygons(rings[members], indices=index)
    built_layer = layer[groups]
    built_body = body[groups]
    return _per_layer(built, built_layer, built_body, report)


def _close_gaps(
    chains: Chains, tol: OutlineTolerances, report: GapReport
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Turn the open chains of each layer into loops; return all loops as flat arrays."""
    if chains.closed.all():
        return chains.coords, chains.offsets, chains.layer, chains.face
    coords_parts = []
    sizes = []
    layers = []
    faces = []
    closed_idx = np.nonzero(chains.closed)[0]
    lo = chains.offsets[closed_idx]
    hi = chains.offsets[closed_idx + 1]
    pick = (
        np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)])
        if len(closed_idx)
        else np.empty(0, dtype=np.int64)
    )
    coords_parts.append(chains.coords[pick])
    sizes.append(hi - lo)
    layers.append(chains.layer[closed_idx])
    faces.append(chains.face[closed_idx])
    open_idx = np.nonzero(~chains.closed)[0]
    # return_index: a plain unique imports numpy.ma
    for lay in np.unique(chains.layer[open_idx], return_index=True)[0]:
        members = open_idx[chains.layer[open_idx] == lay]
        pieces = [chains.coords[chains.offsets[k] : chains.offsets[k + 1]] for k in members]
        loops, gaps, dropped = close_open_chains(
            pieces, tol.stitch_gap, tol.max_gap, tol.hole_gap
        )
        report.closed += gaps
        report.dropped += dropped
        report.gap_layers.add(int(lay))
        for loop in loops:
            coords_parts.append(loop)
            sizes.append(np.array([len(loop)]))
            layers.append(np.array([lay]))
            faces.append(np.array([chains.face[members[0]]]))
    size = np.concatenate(sizes).astype(np.int64)
    return (
        np.concatenate(coords_parts),
        np.concatenate(([0], np.cumsum(size))),
        np.concatenate(layers).astype(np.int64),
        np.concatenate(faces).astype(np.int64),
    )


def _nesting(
    polys: np.ndarray, ccw: np.ndarray, layer: np.ndarray, area: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nesting of loops within each layer: (exterior flags, parent loop of each hole).

    Loops are oriented by the face normals (solid on the left), so a
    counter-clockwise loop bounds solid and a clockwise one a hole, owned by
    the smallest counter-clockwise loop containing it: the nonzero fill rule,
    under which overlapping shells add up instead of cancelling as they would
    by even-odd parity. A clockwise loop that no loop contains cannot be a
    hole; it is taken as solid (a shell with inverted normals). ``polys`` (r,)
    loop polygons without holes; ``ccw`` (r,) bool orientation of each loop.
    """
    n = len(polys)
    bounds = shapely.bounds(polys)
    span = float(np.ptp(bounds[:, [0, 2]]) + 10.0)
    shift = layer * span
    boxes = shapely.box(bounds[:, 0] + shift, bounds[:, 1], bounds[:, 2] + shift, bounds[:, 3])
    tree = shapely.STRtree(boxes)
    inner, outer = tree.query(boxes, predicate="within")
    mask = (inner != outer) & (area[outer] > area[inner])
    inner, outer = inner[mask], outer[mask]
    parent = np.full(n, -1, dtype=np.int64)
    # candidate owners: counter-clockwise loops around clockwise ones
    mask = ccw[outer] & ~ccw[inner]
    inner, outer = inner[mask], outer[mask]
    if len(inner) == 0:
        return np.ones(n, dtype=bool), parent
    probe = shapely.point_on_surface(polys[inner])
    inside = shapely.contains(polys[outer], probe)
    inner, outer = inner[inside], outer[inside]
    exterior = ccw.copy()
    exterior[~ccw] = True
    exterior[inner] = False
    # the direct owner is the smallest one
    order = np.lexsort((area[outer], inner))
    inner_s, outer_s = inner[order], outer[order]
    first = np.ones(len(inner_s), dtype=bool)
    first[1:] = inner_s[1:] != inner_s[:-1]
    parent[inner_s[first]] = outer_s[first]
    return exterior, parent


def _per_layer(
    polys: np.ndarray, layer: np.ndarray, body: np.ndarray, report: GapReport
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Split polygons by layer; layers whose polygons overlap or are invalid are unioned."""
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    order = np.argsort(layer, kind="stable")
    polys, layer, body = polys[order], layer[order], body[order]
    starts = np.flatnonzero(np.diff(layer)) + 1
    firsts = np.concatenate(([0], starts))
    lasts = np.append(starts, len(layer))
    _, index = np.unique(layer, return_inverse=True)
    multi = shapely.multipolygons(polys, indices=index)
    valid = shapely.is_valid(multi)
    for k, (a, b) in enumerate(zip(firsts, lasts, strict=True)):
        lay = int(layer[a])
        p, bd = polys[a:b], body[a:b]
        if not valid[k]:
            p, bd = _repair_layer(p, bd, report)
            report.repaired_layers.add(lay)
        if len(p):
            out[lay] = (p, bd)
    return out


def _repair_layer(
    polys: np.ndarray, body: np.ndarray, report: GapReport
) -> tuple[np.ndarray, np.ndarray]:
    """Make one layer's polygons valid and disjoint (the nonzero fill of overlapping shells).

    Bodies whose regions overlap are reported in ``report.merged`` (they are one
    object) and their union is labelled with the lower body number.
    """
    fixed = shapely.make_valid(polys)
    if len(fixed) > _FEW:
        fixed, body = _uncovered(fixed, body)
    bodies = np.unique(body, return_index=True)[0]  # plain unique imports numpy.ma
    regions = [geom.polygonal(shapely.union_all(fixed[body == b])) for b in bodies]
    label = {int(b): int(b) for b in bodies}
    for i in range(len(bodies)):
        for j in range(i + 1, len(bodies)):
            if shapely.area(geom.intersection(regions[i], regions[j])) > _MIN_RING_AREA:
                report.merged.add((int(bodies[i]), int(bodies[j])))
                label[int(bodies[j])] = label[int(bodies[i])]
    out_p = []
    out_b = []
    for b in sorted(set(label.values())):
        members = [r for k, r in zip(bodies, regions, strict=True) if label[int(k)] == b]
        region = geom.polygonal(shapely.union_all(members))
        parts = shapely.get_parts(region)
        parts = parts[shapely.area(parts) > _MIN_RING_AREA]
        out_p.append(parts)
        out_b.append(np.full(len(parts), b, dtype=np.int64))
    if not out_p:
        return np.empty(0, dtype=object), np.empty(0, dtype=np.int64)
    return np.concatenate(out_p), np.concatenate(out_b)


# a layer of more polygons than this is first rid of those inside another of its body
_FEW = 32


def _uncovered(polys: np.ndarray, body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``polys`` (valid) and their ``body`` without the polygons covered by a larger
    polygon of the same body (or an equal one listed before): they add nothing
    to the body's union. An inlay body of hundreds of loops inside its plate
    (a multibody export) is then one polygon to unite instead of hundreds."""
    tree = shapely.STRtree(polys)
    inner, outer = tree.query(polys, predicate="covered_by")
    area = shapely.area(polys)
    bigger = (area[outer] > area[inner]) | ((area[outer] == area[inner]) & (outer < inner))
    drop = np.zeros(len(polys), dtype=bool)
    drop[inner[bigger & (body[outer] == body[inner]) & (inner != outer)]] = True
    return polys[~drop], body[~drop]
