"""Contour levels that honour the density: no crowding, no large gaps, the right mean spacing.

Level sets of a field ``H`` lie ``dc / |grad H|`` apart for levels ``dc`` apart, so
with evenly spaced levels a field with a varying gradient crowds its contours
where the gradient is steep and leaves gaps where it is flat. Levels here are
``c_j = j * step`` with a *rank* per level, the number of times two divides
``j`` (``j = 0`` has the top rank). Keeping only the levels of rank >= r doubles
the spacing for every unit of r, so each grid cell gets the rank ``r(x)`` that
puts its local spacing ``step * 2**r / |grad H|``:

* never under the line width (no crowding: r at least ``r_min(x)``),
* never over ``gap`` times the target spacing (no holes: r at most ``r_max(x)``),
* otherwise at the field's own spacing (r = ``densify``), which keeps the
  field's character (the stress field keeps more lines where stress is high).

``step`` is then found by bisection so that the predicted path length per area,
``mean(|grad H| / (step * 2**r(x))``, equals ``1 / spacing`` (coarea formula).
Contours of a level stop where the cell's rank exceeds the level's, so spacing
changes by whole octaves with line ends rather than by crowding. The spacing
rule is first order; near a peak or a saddle, where the gradient vanishes,
:func:`holes` finds what it left empty after tracing and :meth:`LevelPlan.opened`
allows finer levels there (never past the crowding limit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage


@dataclass(frozen=True)
class LevelPlan:
    """Levels ``c_j = j * step`` and, per grid cell, the least level rank drawn there.

    ``min_rank`` (ny, nx) int8: level ``j`` is drawn in a cell iff its rank is at
    least the cell's value; ``crowd_rank`` (ny, nx) int8 the least rank that keeps
    contours a line width apart there. ``top`` is the largest rank (given to ``j = 0``).
    """

    step: float
    min_rank: np.ndarray
    crowd_rank: np.ndarray
    top: int

    def opened(self, zone: np.ndarray, octaves: int) -> LevelPlan:
        """The same levels with ``octaves`` more of them allowed in ``zone`` (ny, nx) bool,
        never past ``crowd_rank``: fills holes the first-order spacing rule misses."""
        lowered = np.maximum(self.crowd_rank, self.min_rank - octaves)
        return LevelPlan(
            step=self.step,
            min_rank=np.where(zone, lowered, self.min_rank).astype(np.int8),
            crowd_rank=self.crowd_rank,
            top=self.top,
        )

    def indices(self, low: float, high: float) -> np.ndarray:
        """Level indices j with ``low <= j * step <= high``: (k,) int64."""
        return np.arange(np.ceil(low / self.step), np.floor(high / self.step) + 1).astype(np.int64)

    def ranks(self, j: np.ndarray) -> np.ndarray:
        """Rank of each level index: trailing zero bits of ``j``, capped at ``top``. (k,) int."""
        j = np.asarray(j, dtype=np.int64)
        low_bit = np.where(j == 0, 1, j & -j)
        rank = np.log2(low_bit).astype(int)
        return np.where(j == 0, self.top, np.minimum(rank, self.top))


def plan_levels(
    grad: np.ndarray,
    contour_mask: np.ndarray,
    region_mask: np.ndarray,
    spacing: float,
    min_gap: float,
    cell: float,
    gap: float = 2.0,
    densify: int = 2,
    sparsify: int = 5,
    step: float | None = None,
) -> LevelPlan | None:
    """Choose the level step and the per-cell ranks for one layer.

    ``grad`` (ny, nx) float64, |grad H| in field units per mm; ``contour_mask``
    (ny, nx) bool, cells where contours are traced; ``region_mask`` (ny, nx)
    bool, cells inside the region (where the mean spacing is measured);
    ``spacing`` target mean spacing, ``min_gap`` least spacing (the line width),
    ``cell`` grid cell, all mm; ``gap`` the largest spacing as a multiple of
    ``spacing``; ``densify``/``sparsify`` how many octaves levels may be added or
    skipped locally; ``step`` a level step fixed beforehand (for levels shared by
    every layer) instead of one fitted to this grid. Returns None when the field
    is flat (no level set to draw).
    """
    grad = np.where(np.isfinite(grad), grad, 0.0)
    inside = grad[region_mask]
    if inside.size == 0 or not np.any(inside > 0):
        return None
    floor = max(float(np.percentile(inside, 1.0)), float(inside.max()) * 1e-6)
    log_grad = np.log2(np.maximum(grad, floor))
    size = 2 * int(np.ceil(min_gap / cell)) + 1
    steep = ndimage.maximum_filter(np.where(contour_mask, log_grad, -np.inf), size=size)
    # a hole needs the field flat across it: judge flatness over the gap's own width
    gap_size = 2 * int(np.ceil(0.5 * gap * spacing / cell)) + 1
    flat = ndimage.maximum_filter(np.where(contour_mask, log_grad, -np.inf), size=gap_size)
    high_need = steep + np.log2(min_gap)
    low_need = flat + np.log2(gap * spacing)
    top = densify + sparsify

    def ranks_for(log_step: float, high: np.ndarray, low: np.ndarray) -> np.ndarray:
        r_min = np.ceil(high - log_step)
        r_max = np.floor(low - log_step)
        r = np.maximum(r_min, np.minimum(densify, r_max))
        return np.clip(r, 0, top)

    if step is not None:
        log_step = float(np.log2(step))
        return LevelPlan(
            step=float(step),
            min_rank=ranks_for(log_step, high_need, low_need).astype(np.int8),
            crowd_rank=np.clip(np.ceil(high_need - log_step), 0, top).astype(np.int8),
            top=top,
        )

    sub = (slice(None, None, 2), slice(None, None, 2)) if grad.size > 60_000 else np.s_[:, :]
    sub_mask = region_mask[sub]
    if not sub_mask.any():
        sub, sub_mask = np.s_[:, :], region_mask
    g_sub = grad[sub][sub_mask]
    high_sub, low_sub = high_need[sub][sub_mask], low_need[sub][sub_mask]

    def density(log_step: float) -> float:
        r = ranks_for(log_step, high_sub, low_sub)
        return float(np.mean(g_sub / np.exp2(log_step + r)))

    target = 1.0 / spacing
    start = np.log2(spacing * float(np.mean(inside))) - densify
    lo, hi = start - 10.0, start + 10.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if density(mid) > target:
            lo = mid
        else:
            hi = mid
    log_step = 0.5 * (lo + hi)
    return LevelPlan(
        step=float(np.exp2(log_step)),
        min_rank=ranks_for(log_step, high_need, low_need).astype(np.int8),
        crowd_rank=np.clip(np.ceil(high_need - log_step), 0, top).astype(np.int8),
        top=top,
    )


def holes(
    points: np.ndarray,
    origin: tuple[float, float],
    cell: float,
    region_mask: NDArray[np.bool_],
    radius: float,
) -> NDArray[np.bool_]:
    """Grid nodes inside the region farther than ``radius`` mm from every path point.

    ``points`` (n, 2) float64 mm sampled along the paths (at most a cell apart);
    ``origin`` the (x, y) of node (0, 0); ``region_mask`` (ny, nx) bool. Nodes
    outside the region count as material (the walls). Returns (ny, nx) bool.
    """
    covered = ~region_mask
    if points.size:
        cols = np.clip(
            np.rint((points[:, 0] - origin[0]) / cell).astype(int), 0, covered.shape[1] - 1
        )
        rows = np.clip(
            np.rint((points[:, 1] - origin[1]) / cell).astype(int), 0, covered.shape[0] - 1
        )
        covered = covered.copy()
        covered[rows, cols] = True
    if covered.all():
        return np.zeros_like(region_mask)
    distance: NDArray[np.float64] = ndimage.distance_transform_edt(~covered) * cell
    return (distance > radius) & region_mask
