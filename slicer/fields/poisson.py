"""The Poisson field: laplacian(H) = -1 on the layer domain, H = 0 on its boundary."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.interpolate import RegularGridInterpolator
from scipy.sparse.linalg import spsolve

from slicer.fields.base import LayerContext, register
from slicer.fields.grid import Grid, GridField, grid_over
from slicer.settings import SliceSettings


def solve_poisson(grid: Grid, inside: np.ndarray, source: float = -1.0) -> np.ndarray:
    """Solve laplacian(H) = ``source`` on the nodes ``inside`` with H = 0 elsewhere.

    Five-point finite differences on ``grid``; ``inside`` (ny, nx) bool. Returns H
    (ny, nx) float64 (zero outside; positive inside for a negative source).
    """
    count = int(inside.sum())
    values = np.zeros(inside.shape)
    if count == 0:
        return values
    index = np.full(inside.shape, -1, dtype=np.int64)
    index[inside] = np.arange(count)
    rows = [np.arange(count)]
    cols = [np.arange(count)]
    data = [np.full(count, -4.0)]
    padded = np.pad(index, 1, constant_values=-1)
    r, c = np.nonzero(inside)
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        neighbour = padded[r + 1 + dr, c + 1 + dc]
        ok = neighbour >= 0
        rows.append(index[r[ok], c[ok]])
        cols.append(neighbour[ok])
        data.append(np.ones(int(ok.sum())))
    matrix = sparse.csr_matrix(
        (np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))), shape=(count, count)
    )
    rhs = np.full(count, source * grid.cell**2)
    values[inside] = spsolve(matrix, rhs)
    return values


@register("poisson")
class PoissonField(GridField):
    """H solves laplacian(H) = -1 on the layer's domain with H = 0 on its outline: nested
    smooth loops, steep near the walls and flat in the middle (where levels are added)."""

    name = "poisson"
    cell_fraction = 0.5
    densify = 6  # rings near the peak shrink as the root of the level step: go fine there
    max_cells = 120_000

    def __init__(self, settings: SliceSettings) -> None:
        super().__init__(settings)

    def values(self, grid: Grid, ctx: LayerContext) -> np.ndarray:
        """The solved field on ``grid`` nodes: (ny, nx) float64, 0 outside the domain."""
        return solve_poisson(grid, grid.mask(ctx.domain))

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 (mm^2)."""
        width = self.settings.line_width
        grid = grid_over(ctx.domain, width * self.cell_fraction, self.max_cells, width)
        solved = self.values(grid, ctx)
        xs, ys = grid.axes()
        interpolate = RegularGridInterpolator((ys, xs), solved, bounds_error=False, fill_value=0.0)
        points = np.column_stack((np.ravel(y), np.ravel(x)))
        values: NDArray[np.float64] = interpolate(points).reshape(np.shape(x))
        return values
