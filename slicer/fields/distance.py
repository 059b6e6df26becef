"""Signed distance to a layer outline at many points (KD-tree on the densified boundary)."""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from slicer.fields.paths import prepared


def boundary_points(geom: shapely.Geometry, step: float) -> NDArray[np.float64]:
    """Points along every ring of ``geom``, at most ``step`` mm apart: (n, 2) float64 mm."""
    rings = shapely.boundary(geom)
    points: NDArray[np.float64] = shapely.get_coordinates(shapely.segmentize(rings, step))
    return points


def signed_distance(
    geom: shapely.Geometry, x: np.ndarray, y: np.ndarray, step: float = 0.05
) -> NDArray[np.float64]:
    """Distance from each point to the boundary of ``geom``, positive inside, negative outside.

    ``x``, ``y`` any matching shape, float64 mm; returns the same shape, float64 mm.
    The boundary is sampled every ``step`` mm, so the error is at most ``step / 2``
    next to the boundary and shrinks quadratically away from it.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if geom.is_empty:
        return np.full(x.shape, -np.inf)
    points = boundary_points(geom, step)
    dist, _ = cKDTree(points).query(np.column_stack((x.ravel(), y.ravel())))
    inside = shapely.contains_xy(prepared(geom), x.ravel(), y.ravel())
    signed: NDArray[np.float64] = np.where(inside, dist, -dist).reshape(x.shape)
    return signed
