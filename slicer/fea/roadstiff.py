"""Each analysis box's elasticity from the roads printed through it: fill and direction.

Every layer's roads are drawn on a fine raster, each pixel marked with the road's
direction (one of :data:`BINS` bins over 180 degrees); per box footprint and bin
the covered fraction is taken, and smoothed over :data:`SMOOTH_MM` within the
part (the stiffness of a lattice of roads belongs to the lattice, not to the
0.85 mm box that happens to hold a crossing or a gap). A layer at fill ``phi``
with roads along ``theta`` has the elasticity of :func:`slicer.fea.roadcell.layer_table`
turned to ``theta``; a box's elasticity is the mean of its layers' by how much of
its height each spans (a laminate: the layers are bonded, so they strain alike).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from slicer.fea.anisotropic import isotropic, trig
from slicer.fea.printed import PIXEL_MM, VOID, Roads, paint_roads
from slicer.fea.roadcell import FILLS, layer_table
from slicer.fea.voxel import VoxelGrid

BINS = 12  # road directions told apart, over 180 degrees (15 degrees each)
SMOOTH_MM = 1.0  # the Gaussian (standard deviation) a layer's fill is averaged over


def road_directions(roads: Roads) -> np.ndarray:
    """The bin (0..BINS-1) of each road's direction, modulo 180 degrees: (n,) int64."""
    delta = roads.ends[:, 1] - roads.ends[:, 0]
    angle = np.mod(np.arctan2(delta[:, 1], delta[:, 0]), np.pi)
    out: NDArray[np.int64] = np.mod(np.rint(angle / (np.pi / BINS)), BINS).astype(np.int64)
    return out


def layer_bins(roads: Roads, pick: np.ndarray, grid: VoxelGrid, shift: np.ndarray,
               bins: np.ndarray) -> np.ndarray:
    """Fraction (nx, ny, BINS) of each box footprint that the layer's roads ``pick`` cover,
    by direction bin (a pixel two roads cover counts once, for the last drawn)."""
    nx, ny = grid.solid.shape[:2]
    sub = np.maximum(np.ceil(grid.cell[:2] / PIXEL_MM).astype(int), 1)
    pixel = grid.cell[:2] / sub
    marks = np.zeros((nx * sub[0], ny * sub[1]), dtype=np.int64)  # (x pixels, y pixels)
    ends = roads.ends[pick] + shift[:2] - grid.origin[:2]
    scale = float(np.mean(pixel))
    paint_roads(marks, ends / pixel, roads.width[pick] / scale, bins[pick] + 1)
    bx = np.arange(nx * sub[0]) // sub[0]
    by = np.arange(ny * sub[1]) // sub[1]
    block = (bx[:, None] * ny + by[None, :]) * (BINS + 1) + marks
    counts = np.bincount(block.ravel(), minlength=nx * ny * (BINS + 1))
    out: NDArray[np.float64] = counts.reshape(nx, ny, BINS + 1)[:, :, 1:] / float(sub.prod())
    return out


def _smooth(fractions: np.ndarray, inside: np.ndarray, cell: np.ndarray) -> np.ndarray:
    """Each bin's fraction (nx, ny, BINS) averaged over a Gaussian of :data:`SMOOTH_MM`
    within ``inside`` (nx, ny) only (normalised convolution)."""
    sigma = (SMOOTH_MM / float(cell[0]), SMOOTH_MM / float(cell[1]), 0.0)
    mask = inside.astype(float)
    weight = ndimage.gaussian_filter(mask, sigma[:2], mode="constant")
    spread = ndimage.gaussian_filter(fractions * mask[:, :, None], sigma, mode="constant")
    out: NDArray[np.float64] = np.where(inside[:, :, None],
                                        spread / np.maximum(weight, 1e-12)[:, :, None], 0.0)
    return out


def box_elasticity(roads: Roads, grid: VoxelGrid, shift: np.ndarray, poisson: float,
                   cells: np.ndarray) -> np.ndarray:
    """The elasticity (e, 6, 6) float64 at E = 1 of the boxes ``cells`` (e, 3) int64 of
    ``grid`` built from ``roads`` (``shift`` (3,) mm takes bed coordinates to the
    grid's frame); a box no road reaches keeps :data:`slicer.fea.printed.VOID` of the solid."""
    nx, ny, nz = grid.solid.shape
    height = float(np.median(roads.height)) if len(roads.height) else 0.2
    width = float(np.median(roads.width)) if len(roads.width) else 0.45
    table = layer_table(round(height / width, 2), float(poisson))  # (F, 5, 6, 6)
    fills = np.asarray(FILLS)
    bins = road_directions(roads)
    angles = np.arange(BINS) * np.pi / BINS
    harmonic = trig(angles)  # (BINS, 5)
    bottoms = grid.origin[2] + grid.cell[2] * np.arange(nz)
    total = np.zeros((nx, ny, nz, 6, 6))
    tops = np.unique(np.round(roads.top, 6))
    for top in tops:
        pick = np.abs(roads.top - top) < 1e-6
        thick = float(np.median(roads.height[pick]))
        z0, z1 = top + shift[2] - thick, top + shift[2]
        overlap = np.clip(np.minimum(z1, bottoms + grid.cell[2]) - np.maximum(z0, bottoms), 0,
                          None) / grid.cell[2]
        if not overlap.any():
            continue
        level = int(np.clip((0.5 * (z0 + z1) - grid.origin[2]) // grid.cell[2], 0, nz - 1))
        inside = grid.solid[:, :, level]
        if not inside.any():
            continue
        share = _smooth(layer_bins(roads, pick, grid, shift, bins), inside, grid.cell)
        fill = np.clip(share.sum(axis=2), 0.0, 1.0)  # (nx, ny)
        coeff = np.einsum("xyb,bm->xym", share, harmonic) / np.maximum(fill, 1e-12)[:, :, None]
        at = np.clip(np.searchsorted(fills, fill, side="right") - 1, 0, len(fills) - 2)
        t = (fill - fills[at]) / (fills[at + 1] - fills[at])
        layer = ((1.0 - t)[:, :, None, None, None] * table[at]
                 + t[:, :, None, None, None] * table[at + 1])  # (nx, ny, 5, 6, 6)
        elastic = np.einsum("xym,xymij->xyij", coeff, layer)
        for k in np.flatnonzero(overlap):
            total[:, :, k] += overlap[k] * elastic
    out: NDArray[np.float64] = total[tuple(cells.T)] + VOID * isotropic(poisson)[None]
    return out
