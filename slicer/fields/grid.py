"""Fields sampled on a grid over the layer's region, and their level sets traced on it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from scipy import ndimage
from skimage.measure import find_contours

from slicer.fields.base import LayerContext
from slicer.fields.levels import LevelPlan, plan_levels
from slicer.fields.paths import empty_paths, finish, prepared
from slicer.settings import SliceSettings


@dataclass(frozen=True)
class Grid:
    """A regular grid of ``ny`` rows by ``nx`` columns; node (r, c) sits at
    ``(x0 + c * cell, y0 + r * cell)`` mm."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Node coordinates along x (nx,) and y (ny,), float64 mm."""
        return (
            self.x0 + self.cell * np.arange(self.nx),
            self.y0 + self.cell * np.arange(self.ny),
        )

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Node coordinates X, Y, each (ny, nx) float64 mm."""
        xs, ys = self.axes()
        return np.meshgrid(xs, ys)

    def to_xy(self, rows_cols: np.ndarray) -> np.ndarray:
        """Fractional (row, col) pairs (n, 2) to (x, y) points (n, 2) float64 mm."""
        rows_cols = np.asarray(rows_cols, dtype=float)
        return np.column_stack(
            (self.x0 + rows_cols[:, 1] * self.cell, self.y0 + rows_cols[:, 0] * self.cell)
        )

    def mask(self, geom: shapely.Geometry) -> np.ndarray:
        """Nodes inside ``geom``: (ny, nx) bool."""
        xx, yy = self.mesh()
        return shapely.contains_xy(prepared(geom), xx.ravel(), yy.ravel()).reshape(xx.shape)


def grid_over(geom: shapely.Geometry, cell: float, max_cells: int, margin: float) -> Grid:
    """A grid covering ``geom``'s bounds plus ``margin`` mm, cells of ``cell`` mm or
    coarser so that it has at most ``max_cells`` nodes."""
    xmin, ymin, xmax, ymax = geom.bounds
    width = xmax - xmin + 2.0 * margin
    height = ymax - ymin + 2.0 * margin
    cell = max(cell, math.sqrt(width * height / max_cells))
    return Grid(
        x0=xmin - margin,
        y0=ymin - margin,
        cell=cell,
        nx=math.ceil(width / cell) + 1,
        ny=math.ceil(height / cell) + 1,
    )


def trace_levels(
    grid: Grid, values: np.ndarray, plan: LevelPlan, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Level sets of ``values`` at the plan's levels, each only where its rank is kept.

    ``values`` (ny, nx) float64, ``mask`` (ny, nx) bool nodes to trace in.
    Returns LineStrings (k,) in mm and their level ranks (k,) int.
    """
    finite = np.isfinite(values) & mask
    if not finite.any():
        return np.empty(0, dtype=object), np.empty(0, dtype=int)
    filled = np.where(np.isfinite(values), values, 0.0)
    js = plan.indices(float(values[finite].min()), float(values[finite].max()))
    pieces: list[np.ndarray] = []
    ranks: list[int] = []
    for j, rank in zip(js, plan.ranks(js), strict=True):
        allowed = finite & (plan.min_rank <= rank)
        if not allowed.any():
            continue
        for contour in find_contours(filled, float(j * plan.step), mask=allowed):
            if contour.shape[0] >= 2:
                pieces.append(contour)
                ranks.append(int(rank))
    if not pieces:
        return np.empty(0, dtype=object), np.empty(0, dtype=int)
    owner = np.repeat(np.arange(len(pieces)), [p.shape[0] for p in pieces])
    coords = grid.to_xy(np.concatenate(pieces))
    return shapely.linestrings(coords, indices=owner), np.asarray(ranks)


class GridField:
    """Base for fields with no closed-form level sets: sample on a grid, trace, clip.

    Subclasses set ``name`` and implement :meth:`sample`; they may override
    :meth:`values` (a field solved on the grid) and the class constants:
    ``gap`` (largest local spacing as a multiple of the mean), ``cell_fraction``
    (grid cell as a fraction of the line width), ``max_cells`` and
    ``anchor`` (the level always drawn; the others are whole steps from it) and
    ``refinements``: after tracing, the measured length per area corrects the
    target spacing and the levels are placed again, at most this many times.
    """

    name = "grid"
    gap = 2.0
    cell_fraction = 1.0 / 3.0
    max_cells = 250_000
    refinements = 3
    anchor = 0.0

    def __init__(self, settings: SliceSettings) -> None:
        self.settings = settings

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64."""
        raise NotImplementedError

    def values(self, grid: Grid, ctx: LayerContext) -> np.ndarray:
        """The field on every node of ``grid``: (ny, nx) float64, NaN where undefined."""
        xx, yy = grid.mesh()
        return np.asarray(self.sample(xx.ravel(), yy.ravel(), ctx), dtype=float).reshape(xx.shape)

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Level sets clipped to ``region``, levels placed for mean ``spacing`` mm."""
        width = ctx.settings.line_width
        if region.is_empty or not math.isfinite(spacing) or spacing <= 0:
            return empty_paths()
        region = prepared(region)
        grid = grid_over(region, width * self.cell_fraction, self.max_cells, 2.0 * width)
        values = self.values(grid, ctx) - self.anchor
        region_mask = grid.mask(region)
        if not region_mask.any():
            return empty_paths()
        grow = max(2, math.ceil(width / grid.cell))
        contour_mask = ndimage.binary_dilation(region_mask, iterations=grow)
        contour_mask &= np.isfinite(values)
        grad_y, grad_x = np.gradient(np.where(np.isfinite(values), values, 0.0), grid.cell)
        grad = np.hypot(grad_x, grad_y)
        area = float(region.area)
        best, best_error, target = empty_paths(), math.inf, spacing
        for _ in range(self.refinements + 1):
            plan = plan_levels(
                grad, contour_mask, region_mask & contour_mask, target, width, grid.cell, self.gap
            )
            if plan is None:
                break
            lines, ranks = trace_levels(grid, values, plan, contour_mask)
            paths = finish(lines, region, width, ranks.astype(float))
            achieved = paths.length / area
            error = abs(achieved * spacing - 1.0)
            if error < best_error:
                best, best_error = paths, error
            if error < 0.02 or achieved <= 0:
                break
            target = min(max(target * achieved * spacing, 0.5 * spacing, width), 2.0 * spacing)
        return best
