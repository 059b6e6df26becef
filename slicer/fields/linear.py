"""The paper's linear field (Eq. 13): straight parallel lines, mirrored every other layer.

Its level sets are straight lines, so they are clipped to the region exactly by
a vectorised scanline pass over the region's edges (even-odd pairing of the
crossings on each line) instead of a polygon overlay.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from numpy.typing import NDArray

from slicer.fields.base import LayerContext, register
from slicer.settings import SliceSettings


def line_frame(angle_deg: float, mirror: bool) -> tuple[np.ndarray, np.ndarray]:
    """Unit gradient ``g`` of ``H = x sin t + y cos t * s`` and the direction ``d`` along its lines.

    ``s`` is -1 when ``mirror``. Returns two (2,) float64 vectors.
    """
    t = math.radians(angle_deg)
    sgn = -1.0 if mirror else 1.0
    g = np.array([math.sin(t), math.cos(t) * sgn])
    return g, np.array([-g[1], g[0]])


def hatch(region: shapely.Geometry, angle_deg: float, mirror: bool, spacing: float) -> np.ndarray:
    """Chords of the level sets ``H = k * spacing`` inside ``region``: (n, 2, 2) float64 mm.

    ``region`` is a valid (Multi)Polygon. Levels are anchored at H = 0 (the bed
    origin), so lines line up from layer to layer whatever the region. Each
    edge of every ring is crossed with the levels in ``[min H, max H)`` of its
    ends (half-open, so a vertex on a level is counted once); crossings sorted
    along each level pair up into chords (even-odd: holes are left out).
    Chords come ordered by level, then along the level.
    """
    if region is None or region.is_empty or spacing <= 0:
        return np.empty((0, 2, 2))
    return hatch_many(np.array([region], dtype=object), angle_deg, mirror, spacing)[0]


def hatch_many(
    regions: np.ndarray, angle_deg: float, mirror: bool, spacing: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`hatch` of every region of ``regions`` (r,) at once (None or empty: no chords).

    ``spacing`` mm, one for all or (r,) one per region. Returns the chords (n, 2,
    2) float64 mm and the region each belongs to (n,) int64, ordered by region,
    then as :func:`hatch` orders them.
    """
    none = (np.empty((0, 2, 2)), np.empty(0, dtype=np.int64))
    if np.any(np.asarray(spacing) <= 0) or len(regions) == 0:
        return none
    g, d = line_frame(angle_deg, mirror)
    parts, owner = shapely.get_parts(regions, return_index=True)
    rings, ring_part = shapely.get_rings(parts, return_index=True)
    coords, ring = shapely.get_coordinates(rings, return_index=True)
    same = ring[1:] == ring[:-1]
    p, q = coords[:-1][same], coords[1:][same]
    edge_owner = owner[ring_part[ring[:-1][same]]]
    if isinstance(spacing, np.ndarray):
        spacing = spacing[edge_owner]
    up, uq = p @ g, q @ g
    vp, vq = p @ d, q @ d
    lo = np.minimum(up, uq)
    hi = np.maximum(up, uq)
    k0 = np.ceil(lo / spacing).astype(np.int64)
    k1 = np.ceil(hi / spacing).astype(np.int64)  # exclusive: levels c < hi
    count = np.maximum(k1 - k0, 0)
    total = int(count.sum())
    if total == 0:
        return none
    edge = np.repeat(np.arange(len(count)), count)
    start = np.cumsum(count) - count
    k = k0[edge] + (np.arange(total) - start[edge])
    c = k * (spacing[edge] if isinstance(spacing, np.ndarray) else spacing)
    t = (c - up[edge]) / (uq[edge] - up[edge])
    v = vp[edge] + t * (vq[edge] - vp[edge])
    who = edge_owner[edge]
    order = np.lexsort((v, k, who))
    k, v, c, who = k[order], v[order], c[order], who[order]
    # pair crossings per level of each region: (0, 1), (2, 3), ...
    first = np.concatenate(([True], (k[1:] != k[:-1]) | (who[1:] != who[:-1])))
    rank = np.arange(total) - np.maximum.accumulate(np.where(first, np.arange(total), 0))
    a = np.flatnonzero(rank % 2 == 0)
    a = a[a + 1 < total]
    a = a[~first[a + 1]]
    cc, v0, v1 = c[a], v[a], v[a + 1]
    p0 = cc[:, None] * g + v0[:, None] * d
    p1 = cc[:, None] * g + v1[:, None] * d
    return np.stack([p0, p1], axis=1), who[a]


def line_family(
    region: shapely.Geometry, angle_deg: float, mirror: bool, spacing: float
) -> shapely.Geometry:
    """The chords of :func:`hatch` as a MultiLineString (possibly empty)."""
    chords = hatch(region, angle_deg, mirror, spacing)
    if len(chords) == 0:
        return shapely.MultiLineString()
    return shapely.multilinestrings(shapely.linestrings(chords))


@register("linear")
class LinearField:
    """``H(x, y, z) = x sin t + y cos t (-1)^layer`` with t = ``infill.angle``."""

    name = "linear"

    def __init__(self, settings: SliceSettings) -> None:
        self.angle = settings.infill_angle

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Straight lines at ``spacing`` mm clipped to ``region`` (see :func:`hatch`)."""
        return line_family(region, self.angle, ctx.index % 2 == 1, spacing)

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """H at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 mm."""
        g, _ = line_frame(self.angle, ctx.index % 2 == 1)
        values: NDArray[np.float64] = np.asarray(x) * g[0] + np.asarray(y) * g[1]
        return values
