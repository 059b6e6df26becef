"""Fields sampled on a grid over the layer's region, and their level sets traced on it."""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy import ndimage
from skimage.measure import find_contours

from slicer.fields.base import LayerContext
from slicer.fields.density_levels import density_plan
from slicer.fields.levels import LevelPlan, holes, plan_levels
from slicer.fields.paths import empty_paths, finish, prepared
from slicer.settings import SliceSettings

MAX_LEVELS = 400  # most levels traced on one layer
HOLE_PASSES = 2  # times a layer's levels are opened up where a hole is left
HOLE_OCTAVES = 2  # octaves of finer levels allowed in a hole per pass


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

    def mask(self, geom: shapely.Geometry) -> NDArray[np.bool_]:
        """Nodes inside ``geom``: (ny, nx) bool."""
        xx, yy = self.mesh()
        inside: NDArray[np.bool_] = shapely.contains_xy(prepared(geom), xx.ravel(), yy.ravel())
        return inside.reshape(xx.shape)


def grid_over(
    geom: shapely.Geometry, cell: float, max_cells: int, margin: float, snap: bool = False
) -> Grid:
    """A grid covering ``geom``'s bounds plus ``margin`` mm, cells of ``cell`` mm or
    coarser so that it has at most ``max_cells`` nodes. With ``snap`` the nodes sit
    on multiples of the cell, so layers sharing a cell size sample the same points."""
    xmin, ymin, xmax, ymax = geom.bounds
    width = xmax - xmin + 2.0 * margin
    height = ymax - ymin + 2.0 * margin
    cell = max(cell, math.sqrt(width * height / max_cells))
    x0, y0 = xmin - margin, ymin - margin
    if snap:
        x0, y0 = math.floor(x0 / cell) * cell, math.floor(y0 / cell) * cell
        width, height = xmax + margin - x0, ymax + margin - y0
    return Grid(
        x0=x0,
        y0=y0,
        cell=cell,
        nx=math.ceil(width / cell) + 1,
        ny=math.ceil(height / cell) + 1,
    )


@dataclass(frozen=True)
class _Sampled:
    """A field sampled on a grid over a region, with what level placement needs."""

    grid: Grid
    values: np.ndarray
    region_mask: np.ndarray
    contour_mask: np.ndarray
    grad: np.ndarray
    density: np.ndarray | None = None  # line density asked for, when the field sets one


def trace_levels(
    grid: Grid, values: np.ndarray, plan: LevelPlan, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Level sets of ``values`` at the plan's levels, each only where its rank is kept.

    ``values`` (ny, nx) float64, ``mask`` (ny, nx) bool nodes to trace in.
    Levels are traced rank by rank, each on the smallest window holding the cells
    that admit that rank (fine levels live in small zones); when more than
    ``MAX_LEVELS`` levels span the field, the finest ranks are left out.
    Returns LineStrings (k,) in mm and their level ranks (k,) int.
    """
    finite = np.isfinite(values) & mask
    if not finite.any():
        return np.empty(0, dtype=object), np.empty(0, dtype=int)
    filled = np.where(np.isfinite(values), values, 0.0)
    js = plan.indices(float(values[finite].min()), float(values[finite].max()))
    level_ranks = plan.ranks(js)
    while js.size > MAX_LEVELS:
        keep = level_ranks > level_ranks.min()
        js, level_ranks = js[keep], level_ranks[keep]
    pieces: list[np.ndarray] = []
    ranks: list[int] = []
    for rank in np.unique(level_ranks):
        allowed = finite & (plan.min_rank <= rank)
        rows = np.flatnonzero(allowed.any(axis=1))
        cols = np.flatnonzero(allowed.any(axis=0))
        if rows.size == 0:
            continue
        r0, r1 = max(rows[0] - 1, 0), rows[-1] + 2
        c0, c1 = max(cols[0] - 1, 0), cols[-1] + 2
        window, window_mask = filled[r0:r1, c0:c1], allowed[r0:r1, c0:c1]
        levels = js[level_ranks == rank] * plan.step
        for level, (lr0, lr1, lc0, lc1) in zip(levels, _level_windows(window, window_mask,
                                                                      levels), strict=True):
            if lr1 <= lr0 or lc1 <= lc0:
                continue
            for contour in find_contours(window[lr0:lr1, lc0:lc1], float(level),
                                         mask=window_mask[lr0:lr1, lc0:lc1]):
                if contour.shape[0] >= 2:
                    pieces.append(np.add(contour, (r0 + lr0, c0 + lc0)))
                    ranks.append(int(rank))
    if not pieces:
        return np.empty(0, dtype=object), np.empty(0, dtype=int)
    owner = np.repeat(np.arange(len(pieces)), [p.shape[0] for p in pieces])
    coords = grid.to_xy(np.concatenate(pieces))
    return shapely.linestrings(coords, indices=owner), np.asarray(ranks)


def _level_windows(values: np.ndarray, mask: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """For each level (k,), the smallest window of ``values`` (ny, nx) holding every cell
    whose unmasked corners straddle it: (k, 4) int rows [r0, r1) and columns [c0, c1)
    of nodes (r1 <= r0 or c1 <= c0 when no cell can cross the level).

    A level's contour lies in its window, so tracing it there gives the same
    contour as on the whole grid for a fraction of the work (a line of infill
    crosses a small part of the region).
    """
    low = np.where(mask, values, np.inf)
    high = np.where(mask, values, -np.inf)
    levels = np.asarray(levels, dtype=float)[:, None]
    out = np.zeros((levels.shape[0], 4), dtype=int)
    for axis, (first, last) in ((1, (0, 1)), (0, (2, 3))):
        lo, hi = low.min(axis=axis), high.max(axis=axis)
        cell_lo, cell_hi = np.minimum(lo[:-1], lo[1:]), np.maximum(hi[:-1], hi[1:])
        crossed = (cell_lo[None, :] <= levels) & (cell_hi[None, :] >= levels)
        anyone = crossed.any(axis=1)
        out[:, first] = np.where(anyone, np.argmax(crossed, axis=1), 0)
        out[:, last] = np.where(anyone, crossed.shape[1] - np.argmax(crossed[:, ::-1], axis=1)
                                + 1, 0)
    return out


class GridField:
    """Base for fields with no closed-form level sets: sample on a grid, trace, clip.

    Subclasses set ``name`` and implement :meth:`sample`; they may override
    :meth:`values` (a field solved on the grid) and the class constants:
    ``gap`` (largest local spacing as a multiple of the mean), ``densify`` (how
    many octaves of finer levels may fill flat areas), ``cell_fraction``
    (grid cell as a fraction of the line width), ``max_cells``, ``anchor`` (the
    level always drawn; the others are whole steps from it), ``refinements``
    (after tracing, the measured length per area corrects the target spacing and
    the levels are placed again, at most this many times) and ``shared_levels``:
    a field that does not depend on the layer's region fits its level step once
    on :meth:`reference` and uses it on every layer, on a grid snapped to a
    common lattice, so its paths stack from layer to layer.
    """

    name = "grid"
    gap = 2.0
    cell_fraction = 1.0 / 3.0
    max_cells = 250_000
    refinements = 3
    anchor = 0.0
    shared_levels = False
    densify = 2

    def __init__(self, settings: SliceSettings) -> None:
        self.settings = settings
        # (bounds, spacing, width) -> (target spacing, level step)
        self._steps: dict[tuple[tuple[float, float, float, float], float, float],
                          tuple[float, float]] = {}
        self._lock = threading.Lock()

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64."""
        raise NotImplementedError

    def values(self, grid: Grid, ctx: LayerContext) -> np.ndarray:
        """The field on every node of ``grid``: (ny, nx) float64, NaN where undefined."""
        xx, yy = grid.mesh()
        return np.asarray(self.sample(xx.ravel(), yy.ravel(), ctx), dtype=float).reshape(xx.shape)

    def line_density(self, grid: Grid, ctx: LayerContext) -> np.ndarray | None:
        """A relative line density (ny, nx) float64 the levels must print (see
        :func:`slicer.fields.density_levels.density_plan`; the field's values then
        have unit gradient), or None: levels placed by the field's own spacing."""
        return None

    def reference(self, ctx: LayerContext) -> shapely.Geometry:
        """Where shared levels are fitted: the model's bounding box."""
        return shapely.box(*ctx.bounds)

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Level sets clipped to ``region``, levels placed for mean ``spacing`` mm."""
        width = ctx.settings.line_width
        if region.is_empty or not math.isfinite(spacing) or spacing <= 0:
            return empty_paths()
        region = prepared(region)
        if not self.shared_levels:
            sampled = self._sample(region, ctx, width * self.cell_fraction, snap=False)
            return self._fit(sampled, region, spacing, width)[0] if sampled else empty_paths()
        target, step = self._shared_step(ctx, spacing, width)
        if not math.isfinite(step):
            return empty_paths()
        sampled = self._sample(region, ctx, self._shared_cell(ctx, width), snap=True)
        if sampled is None:
            return empty_paths()
        return self._trace(sampled, region, width, target, step)[0]

    def _shared_cell(self, ctx: LayerContext, width: float) -> float:
        xmin, ymin, xmax, ymax = ctx.bounds
        area = (xmax - xmin + 4.0 * width) * (ymax - ymin + 4.0 * width)
        return max(width * self.cell_fraction, math.sqrt(area / self.max_cells))

    def _shared_step(self, ctx: LayerContext, spacing: float, width: float) -> tuple[float, float]:
        """(target spacing, level step) fitted once on :meth:`reference`, then reused."""
        key = (ctx.bounds, spacing, width)
        with self._lock:
            known = self._steps.get(key)
        if known is not None:
            return known
        reference = prepared(self.reference(ctx))
        sampled = self._sample(reference, ctx, self._shared_cell(ctx, width), snap=True)
        fitted = (spacing, math.inf)
        if sampled is not None:
            _, target, step = self._fit(sampled, reference, spacing, width)
            fitted = (target, step)
        with self._lock:
            self._steps[key] = fitted
        return fitted

    def _sample(
        self, region: shapely.Geometry, ctx: LayerContext, cell: float, snap: bool
    ) -> _Sampled | None:
        width = ctx.settings.line_width
        grid = grid_over(region, cell, self.max_cells, 2.0 * width, snap=snap)
        values = self.values(grid, ctx) - self.anchor
        region_mask = grid.mask(region)
        if not region_mask.any():
            return None
        grow = max(2, math.ceil(width / grid.cell))
        contour_mask = ndimage.binary_dilation(region_mask, iterations=grow)
        contour_mask &= np.isfinite(values)
        grad_y, grad_x = np.gradient(np.where(np.isfinite(values), values, 0.0), grid.cell)
        return _Sampled(grid, values, region_mask, contour_mask, np.hypot(grad_x, grad_y),
                        self.line_density(grid, ctx))

    def _trace(
        self,
        sampled: _Sampled,
        region: shapely.Geometry,
        width: float,
        target: float,
        step: float | None = None,
    ) -> tuple[shapely.Geometry, float]:
        """Paths for one choice of target spacing (and optionally a fixed step),
        with the level step used (inf when the field is flat)."""
        if sampled.density is not None:
            plan = density_plan(sampled.density, sampled.region_mask & sampled.contour_mask,
                                target, width, self.gap)
        else:
            plan = plan_levels(
                sampled.grad,
                sampled.contour_mask,
                sampled.region_mask & sampled.contour_mask,
                target,
                width,
                sampled.grid.cell,
                self.gap,
                densify=self.densify,
                step=step,
            )
        if plan is None:
            return empty_paths(), math.inf
        grid = sampled.grid
        radius = 0.5 * self.gap * target
        for attempt in range(HOLE_PASSES + 1):
            lines, ranks = trace_levels(grid, sampled.values, plan, sampled.contour_mask)
            paths = finish(lines, region, width, ranks.astype(float))
            if attempt == HOLE_PASSES:
                break
            points = shapely.get_coordinates(shapely.segmentize(paths, 0.5 * grid.cell))
            empty = holes(points, (grid.x0, grid.y0), grid.cell, sampled.region_mask, radius)
            if not empty.any():
                break
            zone = ndimage.binary_dilation(empty, iterations=max(1, math.ceil(radius / grid.cell)))
            plan = plan.opened(zone, HOLE_OCTAVES)
        return paths, plan.step

    def _fit(
        self, sampled: _Sampled, region: shapely.Geometry, spacing: float, width: float
    ) -> tuple[shapely.Geometry, float, float]:
        """Paths whose length per area best matches ``1 / spacing``, with the target
        spacing and level step that gave them."""
        area = float(region.area)
        best, best_error, best_target, best_step = empty_paths(), math.inf, spacing, math.inf
        target = spacing
        for _ in range(self.refinements + 1):
            paths, step = self._trace(sampled, region, width, target)
            if not math.isfinite(step):
                break
            achieved = paths.length / area
            error = abs(achieved * spacing - 1.0)
            if error < best_error:
                best, best_error, best_target, best_step = paths, error, target, step
            if error < 0.02 or achieved <= 0:
                break
            target = min(max(target * achieved * spacing, 0.5 * spacing, width), 2.0 * spacing)
        return best, best_target, best_step
