"""The random field: distance to seeded random points, a Voronoi-like cell pattern."""

from __future__ import annotations

import math

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from slicer.fields.base import LayerContext, register
from slicer.fields.paths import empty_paths, finish, linestring_parts
from slicer.settings import SliceSettings

MAX_POINTS = 5000


@register("random")
class RandomField:
    """H = distance to the nearest of random points, about one per ``infill.scale``^2 mm^2.

    The points depend only on ``infill.seed`` and the layer index (numpy's
    Generator seeded with both), so a layer re-sliced alone is identical. Level
    sets are circles merging into cells: exactly the boundaries of the unions of
    disks of radius c_k, built with shapely.
    """

    name = "random"

    def __init__(self, settings: SliceSettings) -> None:
        self.settings = settings

    def points(self, ctx: LayerContext) -> np.ndarray:
        """The layer's seed points: (n, 2) float64 mm, spread over the model's bounds."""
        xmin, ymin, xmax, ymax = ctx.bounds
        scale = self.settings.infill_scale
        xmin, ymin, xmax, ymax = xmin - scale, ymin - scale, xmax + scale, ymax + scale
        count = int(np.clip(round((xmax - xmin) * (ymax - ymin) / scale**2), 1, MAX_POINTS))
        rng = np.random.default_rng([self.settings.infill_seed, ctx.index])
        return rng.uniform((xmin, ymin), (xmax, ymax), size=(count, 2))

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 mm."""
        dist, _ = cKDTree(self.points(ctx)).query(np.column_stack((np.ravel(x), np.ravel(y))))
        values: NDArray[np.float64] = dist.reshape(np.shape(x))
        return values

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Level sets at ``(k + 1/2) * spacing`` mm of distance, clipped to ``region``."""
        if region.is_empty or not math.isfinite(spacing) or spacing <= 0:
            return empty_paths()
        seeds = self.points(ctx)
        probe = shapely.get_coordinates(shapely.segmentize(shapely.boundary(region), spacing / 2))
        xmin, ymin, xmax, ymax = region.bounds
        gx, gy = np.meshgrid(np.arange(xmin, xmax, spacing / 2), np.arange(ymin, ymax, spacing / 2))
        probe = np.vstack((probe, np.column_stack((gx.ravel(), gy.ravel()))))
        dist, _ = cKDTree(seeds).query(probe)
        lo, hi = float(dist.min()), float(dist.max()) + spacing
        levels = (np.arange(math.floor(lo / spacing), math.ceil(hi / spacing)) + 0.5) * spacing
        near = shapely.intersects(
            shapely.buffer(region, float(levels.max())), shapely.points(seeds)
        )
        disks = shapely.buffer(shapely.points(seeds[near])[None, :], levels[:, None], quad_segs=16)
        unions = shapely.union_all(disks, axis=1)
        rings = linestring_parts(shapely.boundary(unions))
        return finish(rings, region, self.settings.line_width)
