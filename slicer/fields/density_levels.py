"""Levels that print a density: straight lines a step apart, thinned by whole octaves."""

from __future__ import annotations

import math

import numpy as np

from slicer.fields.levels import LevelPlan


def density_plan(
    density: np.ndarray, region_mask: np.ndarray, spacing: float, min_gap: float, gap: float
) -> LevelPlan | None:
    """Level plan for a field of unit gradient (parallel straight lines, level ``j`` at
    ``j * step`` mm) whose line density follows ``density``.

    ``density`` (ny, nx) float64 > 0 on the grid, relative; ``region_mask`` (ny, nx)
    bool where the infill is (where the mean is measured); ``spacing`` the target
    mean spacing, ``min_gap`` the least (the line width), ``gap`` the largest as a
    multiple of ``spacing``; mm. A cell of density ``rho`` gets the rank
    ``round(log2(s / rho))`` (the lines kept there are ``step * 2**rank`` apart:
    spacing inversely proportional to the density, to the nearest octave), at
    least 0 and at most what keeps gaps under ``gap * spacing``. ``s`` is the
    largest scale (at most the densest cell's density, which then gets the finest
    lines) at which the step that gives the mean spacing,
    ``spacing * mean(2**-rank)`` (the coarea formula for unit gradient), is still
    at least ``min_gap``. Returns None when the region is empty.
    """
    inside = region_mask & np.isfinite(density)
    if not inside.any():
        return None
    rho = np.maximum(np.where(np.isfinite(density), density, 0.0), 1e-9)
    log_rho = np.log2(rho)
    peak = float(log_rho[inside].max())
    top = max(0, math.floor(math.log2(gap * spacing / min_gap)))

    def ranks_for(log_s: float, cap: int) -> np.ndarray:
        return np.clip(np.rint(log_s - log_rho), 0, cap)

    def step_for(log_s: float, cap: int) -> float:
        return spacing * float(np.mean(np.exp2(-ranks_for(log_s, cap)[inside])))

    for _ in range(2):  # the second pass caps the sparsest gaps at the step found
        lo, hi = peak - top - 1.0, peak
        if step_for(hi, top) >= min_gap:
            lo = hi
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if step_for(mid, top) >= min_gap:
                lo = mid
            else:
                hi = mid
        ranks, step = ranks_for(lo, top), step_for(lo, top)
        cap = max(0, math.floor(math.log2(gap * spacing / step)))
        if cap >= top:
            break
        top = cap
    return LevelPlan(step=step, min_rank=ranks.astype(np.int8),
                     crowd_rank=np.zeros(rho.shape, dtype=np.int8), top=max(top, 1))
