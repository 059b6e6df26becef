"""Narrow skin filled along its length: concentric lines in the thin bands of sloped shells.

The shells of sloped surfaces make skin in bands a few lines wide under the
walls of the layers above. Hatched across, such a band is a run of chords as
short as its width, two moves each; filled with inward offsets of the band
(half a line in from its edge, a line apart, the concentric field's paths),
it is a few long smooth lines that arcs and the line budget take in few
moves. Parts wider than :data:`NARROW` lines somewhere keep the hatch.

It is done when the G-code is made for a wire (arcs on, or the link's baud
known: :func:`wanted`), where lines cost: it doubles the CPU time of a
layer's toolpaths on sloped models (3DBenchy), which a batch slice keeps.
"""

from __future__ import annotations

import numpy as np
import shapely

from slicer.geometry import geom
from slicer.paths.arcs import arcs_wanted
from slicer.settings import SliceSettings

# skin parts that an inward offset by half this many line widths empties are filled along
# their length
NARROW = 4.0
# share of a line width below which two offsets are too close (they are a whole one apart)
_APART = 0.9
# the first line is kept where it passes within this share of a line of the band
_REACH = 0.25
# gaps the narrow lines leave are hatched where wider than twice this share of a line
_GAP = 0.25
# arcs of offset corners: segments per quarter circle
_QUAD_SEGS = 6


def wanted(settings: SliceSettings) -> bool:
    """Whether narrow skin is filled along its length: arcs on, or ``gcode.baud`` known."""
    return arcs_wanted(settings) or settings.gcode_baud > 0


def split_narrow(skin: np.ndarray, w: float) -> tuple[np.ndarray, np.ndarray]:
    """Each island's skin ``skin`` ((p,) (Multi)Polygon or None) split into its parts
    narrower than :data:`NARROW` line widths ``w`` mm everywhere and the rest: two (p,)
    arrays, the narrow skin valid (its parts united) or None."""
    narrow = np.full(len(skin), None, dtype=object)
    wide = skin.copy()
    has = np.array([g is not None and not g.is_empty for g in skin], dtype=bool)
    if not has.any():
        return narrow, wide
    parts, owner = shapely.get_parts(skin[has], return_index=True)
    owner = np.flatnonzero(has)[owner]
    thin = shapely.is_empty(shapely.buffer(parts, -0.5 * NARROW * w, quad_segs=_QUAD_SEGS))
    if not thin.any():
        return narrow, wide
    for i in np.unique(owner[thin], return_index=True)[0].tolist():  # plain unique imports numpy.ma
        mine = owner == i
        # a skin's parts may touch along edges (solid small regions beside it): united
        narrow[i] = shapely.union_all(parts[mine & thin])
        rest = parts[mine & ~thin]
        wide[i] = shapely.multipolygons(rest) if len(rest) else None
    return narrow, wide


def along(
    narrow: np.ndarray, wide: np.ndarray, fill: np.ndarray, w: float
) -> tuple[list[list[np.ndarray]], np.ndarray]:
    """The lines of each island's narrow skin (``narrow`` (p,) MultiPolygon or None) and
    the skin left to the hatch.

    The lines are the level sets of the distance to the edge of the island's infill
    domain ``fill`` ((p,) Polygon) at ``(k + 1/2) w`` mm (the walls' own field, continued
    inward), kept where they run in the band: the first within half a line of it (a band
    thinner than a line gets one line), the others inside it. Returned as point arrays
    (k, 2) mm per island, and ``wide`` ((p,) the skin left to the hatch) with what the
    lines leave uncovered added (bands away from the domain's edge, strips wider than
    ``2 _GAP`` lines), so the skin stays solid."""
    # the paths' tidying needs scipy, which a layer without narrow skin never loads
    from slicer.fields.paths import finish

    out: list[list[np.ndarray]] = [[] for _ in range(len(narrow))]
    has = [i for i, g in enumerate(narrow) if g is not None and not g.is_empty]
    if not has:
        return out, wide
    wide = wide.copy()
    depth = (np.arange(int(NARROW)) + 0.5) * w
    regions = narrow[has]
    # level k can run inside a band only where the band is more than its depth wide: the
    # levels no band of the island reaches are not made (most bands take one line)
    reach = ~shapely.is_empty(shapely.buffer(regions[:, None], -0.5 * depth[None, 1:],
                                             quad_segs=_QUAD_SEGS))
    needed = np.column_stack([np.ones(len(has), dtype=bool), reach])
    row_of, level = np.nonzero(needed)
    zone0 = shapely.buffer(regions, _REACH * w, quad_segs=_QUAD_SEGS)
    rings = shapely.boundary(shapely.buffer(fill[has][row_of], -depth[level],
                                            quad_segs=_QUAD_SEGS))
    pieces = geom.intersection(rings, np.where(level == 0, zone0[row_of], regions[row_of]))
    parts, source = shapely.get_parts(pieces, return_index=True)
    line = (shapely.get_type_id(parts) == 1) & (shapely.length(parts) > 0.0)
    parts, part_row = parts[line], row_of[source[line]]
    for row, i in enumerate(has):
        lines = parts[part_row == row]
        if len(lines):
            # neighbouring levels lie exactly a line apart: only closer ones (where a
            # level folds on itself) are kept apart
            lines = shapely.get_parts(finish(lines, zone0[row], _APART * w))
        if len(lines):
            coords, index = shapely.get_coordinates(lines, return_index=True)
            out[i] = geom.split_rows(coords, np.flatnonzero(np.diff(index)) + 1)
            # each line apart, then united (one buffer of them all can come out invalid)
            covered = shapely.union_all(shapely.buffer(lines, 0.5 * w, quad_segs=_QUAD_SEGS))
            left = geom.difference(regions[row], covered)
        else:
            left = regions[row]
        # strips thinner than twice _GAP lines are left, as hair-thin skin is (skins.py)
        left = shapely.buffer(shapely.buffer(left, -_GAP * w, quad_segs=_QUAD_SEGS),
                              _GAP * w, quad_segs=_QUAD_SEGS)
        left_parts = shapely.get_parts(geom.intersection(left, regions[row]))
        left_parts = left_parts[shapely.get_type_id(left_parts) == 3]
        if len(left_parts):
            base = wide[i]
            keep = [] if base is None or base.is_empty else list(shapely.get_parts(base))
            wide[i] = shapely.multipolygons(keep + list(left_parts))
    return out, wide
