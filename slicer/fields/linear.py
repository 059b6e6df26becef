"""The paper's linear field (Eq. 13): straight parallel lines, mirrored every other layer."""

from __future__ import annotations

import math

import numpy as np
import shapely

from slicer.fields.base import LayerContext, register
from slicer.settings import SliceSettings


def line_family(
    region: shapely.Geometry, angle_deg: float, mirror: bool, spacing: float
) -> shapely.Geometry:
    """Level sets of ``H = x sin t + y cos t * s`` at ``c_k = k * spacing``, clipped to ``region``.

    ``t`` is ``angle_deg`` in radians; ``s`` is -1 when ``mirror``, else 1. The
    levels are anchored at H = 0 (the bed origin), so lines line up from layer to
    layer whatever the region. Returns a MultiLineString (possibly empty): the
    clipped lines, one part per chord, in one vectorised shapely call.
    """
    if region.is_empty or spacing <= 0:
        return shapely.MultiLineString()
    t = math.radians(angle_deg)
    sgn = -1.0 if mirror else 1.0
    # unit gradient of H and the direction along its level sets
    gx, gy = math.sin(t), math.cos(t) * sgn
    dx, dy = -gy, gx
    xmin, ymin, xmax, ymax = region.bounds
    corners = np.array([[xmin, ymin], [xmin, ymax], [xmax, ymin], [xmax, ymax]])
    h = corners @ np.array([gx, gy])
    s = corners @ np.array([dx, dy])
    k = np.arange(math.floor(h.min() / spacing), math.ceil(h.max() / spacing) + 1)
    if len(k) == 0:
        return shapely.MultiLineString()
    c = k * spacing
    s0, s1 = s.min() - 1.0, s.max() + 1.0
    p0 = np.stack([c * gx + s0 * dx, c * gy + s0 * dy], axis=1)
    p1 = np.stack([c * gx + s1 * dx, c * gy + s1 * dy], axis=1)
    lines = shapely.multilinestrings(shapely.linestrings(np.stack([p0, p1], axis=1)))
    return shapely.intersection(lines, region)


@register("linear")
class LinearField:
    """``H(x, y, z) = x sin t + y cos t (-1)^layer`` with t = ``infill.angle``."""

    name = "linear"

    def __init__(self, settings: SliceSettings) -> None:
        self.angle = settings.infill_angle

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Straight lines at ``spacing`` mm clipped to ``region`` (see :func:`line_family`)."""
        return line_family(region, self.angle, ctx.index % 2 == 1, spacing)

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """H at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 mm."""
        t = math.radians(self.angle)
        sgn = -1.0 if ctx.index % 2 == 1 else 1.0
        return np.asarray(x) * math.sin(t) + np.asarray(y) * math.cos(t) * sgn
