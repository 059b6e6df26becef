"""The concentric field: the signed distance to the outline; its level sets are inward offsets."""

from __future__ import annotations

import math

import numpy as np
import shapely

from slicer.fields.base import LayerContext, register
from slicer.fields.distance import signed_distance
from slicer.fields.paths import empty_paths, finish, linestring_parts
from slicer.settings import SliceSettings


@register("concentric")
class ConcentricField:
    """H = signed distance to the layer outline (the paper's H_pr); paths are exact
    inward offsets of the region, half a spacing in from its edge and a spacing apart."""

    name = "concentric"

    def __init__(self, settings: SliceSettings) -> None:
        self.settings = settings

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 mm, >0 inside."""
        return signed_distance(ctx.domain, x, y, step=self.settings.line_width / 8.0)

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Offsets of ``region`` by ``(k + 1/2) * spacing`` mm, k = 0, 1, ... while any remain."""
        if region.is_empty or not math.isfinite(spacing) or spacing <= 0:
            return empty_paths()
        circle = shapely.maximum_inscribed_circle(region, tolerance=spacing / 20.0)
        depth = float(shapely.length(circle))
        offsets = (np.arange(int(depth / spacing + 1.0)) + 0.5) * spacing
        offsets = offsets[offsets < depth]
        if offsets.size == 0:
            return empty_paths()
        shells = shapely.buffer(region, -offsets, quad_segs=8)
        rings = linestring_parts(shapely.boundary(shells[~shapely.is_empty(shells)]))
        return finish(rings, region, self.settings.line_width)
