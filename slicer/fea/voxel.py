"""Voxelising a closed triangle mesh: which cubes of a regular lattice lie inside it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_CELLS = 16_000  # boxes the default mesh size aims for in the part's volume
MIN_CELL_MM = 0.2  # the finest default cube edge
MAX_VOXELS = 4_000_000  # lattice cells (inside or not) a voxelisation may span
# column centres are nudged off the lattice by this fraction of a cell so that a ray
# never runs exactly along an edge of a mesh whose vertices sit on round numbers
_NUDGE = (math.sqrt(2.0) - 1.0) * 1e-3


@dataclass(frozen=True)
class VoxelGrid:
    """Boxes of edges ``cell`` (3,) mm; box (i, j, k) spans ``origin + cell * [i, i+1] x ...``.

    ``solid`` (nx, ny, nz) bool: the box's centre lies inside the mesh.
    ``origin`` (3,) float64 mm is the mesh's least corner, in the model's own frame.
    The edges are the asked mesh size stretched a little per axis so that a whole
    number of boxes spans the mesh's extent exactly (a prism is represented exactly).
    """

    origin: np.ndarray
    cell: np.ndarray
    solid: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        """Cubes along x, y, z."""
        return tuple(int(n) for n in self.solid.shape)  # type: ignore[return-value]

    def centres(self, index: np.ndarray) -> np.ndarray:
        """Centres of cubes ``index`` (n, 3) int -> (n, 3) float64 mm."""
        return self.origin + self.cell * (np.asarray(index, dtype=float) + 0.5)


def default_cell(volume_mm3: float, cells: int = DEFAULT_CELLS) -> float:
    """The default cube edge, mm: the part's ``volume_mm3`` cut into about ``cells`` cubes,
    rounded to 0.05 mm and never under :data:`MIN_CELL_MM`."""
    edge: float = (max(volume_mm3, 1e-9) / cells) ** (1.0 / 3.0)  # float ** float types as Any
    return max(MIN_CELL_MM, round(edge / 0.05) * 0.05)


def mesh_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed mesh, mm^3 (absolute value of the signed volume)."""
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    return abs(float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0)


def voxelize(vertices: np.ndarray, faces: np.ndarray, size: float) -> VoxelGrid:
    """The boxes of edges about ``size`` mm whose centres lie inside the closed mesh.

    ``vertices`` (v, 3) float64 mm, ``faces`` (f, 3) int. Every column of cube
    centres is a ray along z: its crossings with the triangles are counted
    below each centre (even-odd rule), all columns at once, so the cost grows
    with the triangles and the columns they cover, not with a loop in Python.
    Raises ValueError when the lattice would exceed :data:`MAX_VOXELS` cells.
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    lo = vertices.min(axis=0)
    hi = vertices.max(axis=0)
    extent = np.maximum(hi - lo, 1e-9)
    shape = np.maximum(np.rint(extent / size).astype(np.int64), 1)
    if int(np.prod(shape)) > MAX_VOXELS:
        raise ValueError(
            f"a {size:g} mm mesh of this part needs {int(np.prod(shape))} cells, over "
            f"{MAX_VOXELS}: use a coarser mesh size"
        )
    cell = extent / shape
    nx, ny, nz = (int(n) for n in shape)
    tri = (vertices[faces] - lo) / cell  # (f, 3, 3) in cell units
    nudge = _NUDGE
    # columns (i, j) each triangle's xy box may cover: centre at i + 0.5 + nudge
    tmin = tri[:, :, :2].min(axis=1)
    tmax = tri[:, :, :2].max(axis=1)
    i0 = np.clip(np.ceil(tmin - 0.5 - nudge), 0, None).astype(np.int64)
    i1 = np.minimum(np.floor(tmax - 0.5 - nudge), shape[:2] - 1).astype(np.int64)
    span = np.maximum(i1 - i0 + 1, 0)
    counts = span[:, 0] * span[:, 1]
    total = int(counts.sum())
    solid = np.zeros((nx, ny, nz), dtype=bool)
    if total == 0:
        return VoxelGrid(lo, cell, solid)
    owner = np.repeat(np.arange(len(tri)), counts)
    local = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    ci = i0[owner, 0] + local // np.maximum(span[owner, 1], 1)
    cj = i0[owner, 1] + local % np.maximum(span[owner, 1], 1)
    px = ci + 0.5 + nudge
    py = cj + 0.5 + nudge * 0.7071
    a, b, c = tri[owner, 0], tri[owner, 1], tri[owner, 2]
    # barycentric coordinates of (px, py) in the triangle's xy projection
    det = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    ok = np.abs(det) > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = ((b[:, 1] - c[:, 1]) * (px - c[:, 0]) + (c[:, 0] - b[:, 0]) * (py - c[:, 1])) / det
        l2 = ((c[:, 1] - a[:, 1]) * (px - c[:, 0]) + (a[:, 0] - c[:, 0]) * (py - c[:, 1])) / det
        l3 = 1.0 - l1 - l2
        hit = ok & (l1 >= 0) & (l2 >= 0) & (l3 >= 0)
    z = l1[hit] * a[hit, 2] + l2[hit] * b[hit, 2] + l3[hit] * c[hit, 2]
    # the crossing counts for every centre above it: centre k sits at k + 0.5
    k = np.clip(np.ceil(z - 0.5), 0, nz).astype(np.int64)
    flat = (ci[hit] * ny + cj[hit]) * (nz + 1) + k
    crossings = np.bincount(flat, minlength=nx * ny * (nz + 1)).reshape(nx, ny, nz + 1)
    solid = (np.cumsum(crossings, axis=2)[:, :, :nz] % 2) == 1
    return VoxelGrid(lo, cell, solid)
