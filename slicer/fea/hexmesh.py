"""Trilinear hexahedra on a voxel lattice: nodes, element stiffness (scikit-fem), surface faces."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from slicer.fea.voxel import VoxelGrid

# corner a of a box sits at offset (a & 1, (a >> 1) & 1, (a >> 2) & 1) in cells
CORNERS = np.array([[a & 1, (a >> 1) & 1, (a >> 2) & 1] for a in range(8)], dtype=np.int64)
# the four corners of each side: (axis, side) -> corner numbers
_SIDE_CORNERS = {
    (axis, side): np.flatnonzero(CORNERS[:, axis] == side) for axis in range(3) for side in (0, 1)
}


@dataclass(frozen=True)
class HexMesh:
    """The solid boxes of a voxel grid as 8-node hexahedra.

    ``cells`` (e, 3) int64 lattice index of each element; ``nodes`` (e, 8) int64
    node of each corner (see :data:`CORNERS`); ``points`` (n, 3) float64 mm node
    positions in the model frame; ``body`` (e,) int64 the face-connected body of
    each element (0..bodies-1). Bodies touching only along an edge or at a corner
    get nodes of their own there: such a joint transmits no moment and would
    leave the part free to hinge.
    """

    grid: VoxelGrid
    cells: np.ndarray
    nodes: np.ndarray
    points: np.ndarray
    body: np.ndarray
    bodies: int

    @property
    def dofs(self) -> np.ndarray:
        """Degrees of freedom of each element (e, 24) int64: 3 * node + component."""
        return (3 * self.nodes[:, :, None] + np.arange(3)).reshape(len(self.nodes), 24)

    @property
    def centres(self) -> np.ndarray:
        """Element centres (e, 3) float64 mm."""
        return self.grid.centres(self.cells)


def hex_mesh(grid: VoxelGrid) -> HexMesh:
    """Elements, nodes and bodies of the solid boxes of ``grid``."""
    labels, count = ndimage.label(grid.solid)  # 6-connected: bodies share whole faces
    cells = np.argwhere(grid.solid).astype(np.int64)
    body = labels[tuple(cells.T)].astype(np.int64) - 1
    lattice = np.array(grid.solid.shape) + 1
    corner = cells[:, None, :] + CORNERS[None, :, :]  # (e, 8, 3)
    flat = np.ravel_multi_index(tuple(np.moveaxis(corner, -1, 0)), lattice)
    key = body[:, None] * int(np.prod(lattice)) + flat
    unique, inverse = np.unique(key, return_inverse=True)
    nodes = inverse.reshape(len(cells), 8).astype(np.int64)
    node_index = np.array(np.unravel_index(unique % int(np.prod(lattice)), lattice)).T
    points = grid.origin + node_index * grid.cell
    return HexMesh(grid, cells, nodes, points, body, int(count))


@lru_cache(maxsize=8)
def _element_matrix(hx: float, hy: float, hz: float, poisson: float) -> np.ndarray:
    """Stiffness of one box element for E = 1 MPa: (24, 24) float64, N/mm per unit E,
    dofs ordered 3 * corner + component. Assembled by scikit-fem on a one-element mesh."""
    from skfem import Basis, ElementHex1, ElementVector, MeshHex, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = MeshHex.init_tensor(np.array([0.0, hx]), np.array([0.0, hy]), np.array([0.0, hz]))
    basis = Basis(mesh, ElementVector(ElementHex1()))
    stiffness = asm(linear_elasticity(*lame_parameters(1.0, poisson)), basis).toarray()
    offsets = np.rint(mesh.p.T / np.array([hx, hy, hz])).astype(np.int64)  # (8, 3)
    mine = offsets[:, 0] + 2 * offsets[:, 1] + 4 * offsets[:, 2]  # my corner of skfem node n
    order = np.empty(24, dtype=np.int64)
    for node, corner in enumerate(mine):
        for comp in range(3):
            order[3 * corner + comp] = basis.nodal_dofs[comp, node]
    reordered: NDArray[np.float64] = stiffness[np.ix_(order, order)]
    return reordered


def element_matrix(cell: np.ndarray, poisson: float) -> np.ndarray:
    """Stiffness (24, 24) float64 of one box of edges ``cell`` (3,) mm at E = 1 MPa."""
    return _element_matrix(float(cell[0]), float(cell[1]), float(cell[2]), float(poisson))


def strain_matrix(cell: np.ndarray) -> np.ndarray:
    """Strain at a box's centre from its 24 corner displacements: (6, 24) float64.

    Strains in Voigt order (xx, yy, zz, yz, xz, xy), shear as engineering strain.
    """
    sign = 2.0 * CORNERS - 1.0  # (8, 3) of +-1
    grad = sign / (4.0 * np.asarray(cell, dtype=float))  # dN_a/dx_i at the centre, (8, 3)
    b = np.zeros((6, 24))
    for a in range(8):
        gx, gy, gz = grad[a]
        b[0, 3 * a] = gx
        b[1, 3 * a + 1] = gy
        b[2, 3 * a + 2] = gz
        b[3, 3 * a + 1], b[3, 3 * a + 2] = gz, gy
        b[4, 3 * a], b[4, 3 * a + 2] = gz, gx
        b[5, 3 * a], b[5, 3 * a + 1] = gy, gx
    return b


def elasticity_matrix(poisson: float) -> np.ndarray:
    """Isotropic stress-strain matrix (6, 6) float64 at E = 1, Voigt order as above."""
    nu = poisson
    scale = 1.0 / ((1.0 + nu) * (1.0 - 2.0 * nu))
    d = np.zeros((6, 6))
    d[:3, :3] = nu
    np.fill_diagonal(d[:3, :3], 1.0 - nu)
    d[3:, 3:] = np.eye(3) * (1.0 - 2.0 * nu) / 2.0
    return d * scale


@dataclass(frozen=True)
class Faces:
    """The boundary faces of a hex mesh (elements' sides with no solid neighbour).

    ``centre`` (m, 3) float64 mm; ``axis_normal`` (m, 3) outward unit normal of the
    face itself; ``smooth_normal`` (m, 3) the surface's outward normal there,
    estimated from the blurred solid (a staircase of faces on a slope gets the
    slope's normal); ``area`` (m,) mm^2; ``nodes`` (m, 4) int64; ``body`` (m,) int64.
    """

    centre: np.ndarray
    axis_normal: np.ndarray
    smooth_normal: np.ndarray
    area: np.ndarray
    nodes: np.ndarray
    body: np.ndarray


def boundary_faces(mesh: HexMesh) -> Faces:
    """Every element side that no solid element shares (see :class:`Faces`)."""
    grid = mesh.grid
    solid = grid.solid
    padded = np.pad(solid, 1)
    blurred = ndimage.gaussian_filter(padded.astype(float), sigma=1.0)
    gradient = np.stack(np.gradient(blurred, *grid.cell), axis=-1)  # (nx+2, ny+2, nz+2, 3)
    parts: list[tuple[np.ndarray, ...]] = []
    for axis in range(3):
        for side in (0, 1):
            step = np.zeros(3, dtype=np.int64)
            step[axis] = 1 if side else -1
            neighbour = mesh.cells + step + 1  # in padded indices
            open_side = ~padded[tuple(neighbour.T)]
            which = np.flatnonzero(open_side)
            if which.size == 0:
                continue
            normal = np.zeros((which.size, 3))
            normal[:, axis] = 1.0 if side else -1.0
            centre = mesh.centres[which] + 0.5 * grid.cell * normal
            inner = mesh.cells[which] + 1
            outer = inner + step
            slope = gradient[tuple(inner.T)] + gradient[tuple(outer.T)]
            length = np.linalg.norm(slope, axis=1, keepdims=True)
            smooth = np.where(length > 1e-12, -slope / np.maximum(length, 1e-300), normal)
            others = [k for k in range(3) if k != axis]
            area = np.full(which.size, grid.cell[others[0]] * grid.cell[others[1]])
            nodes = mesh.nodes[which][:, _SIDE_CORNERS[(axis, side)]]
            parts.append((centre, normal, smooth, area, nodes, mesh.body[which]))
    if not parts:
        empty = np.empty((0, 3))
        return Faces(empty, empty, empty, np.empty(0), np.empty((0, 4), np.int64),
                     np.empty(0, np.int64))
    columns = list(zip(*parts, strict=True))
    return Faces(*(np.concatenate(c) for c in columns))
