"""Anisotropic boxes: element stiffness from any 6 x 6 elasticity, rotation about z, assembly."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from slicer.fea.hexmesh import CORNERS, HexMesh, elasticity_matrix

CHUNK = 2048  # elements whose matrices are built and assembled at a time
_GAUSS = 0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)  # 2-point rule on [0, 1]
# Voigt order (xx, yy, zz, yz, xz, xy): the index pair of each entry
_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


@lru_cache(maxsize=8)
def _gauss_strains(hx: float, hy: float, hz: float) -> np.ndarray:
    """Strain matrices (8, 6, 24) float64 at the 2 x 2 x 2 Gauss points of a box."""
    cell = np.array([hx, hy, hz])
    out = np.zeros((8, 6, 24))
    for g in range(8):
        xi = np.array([_GAUSS[(g >> a) & 1] for a in range(3)])
        # trilinear shape functions N_a = prod(c xi + (1 - c)(1 - xi)); their gradients
        factors = np.where(CORNERS == 1, xi, 1.0 - xi)  # (8, 3)
        slope = np.where(CORNERS == 1, 1.0, -1.0) / cell  # d factor / dx
        grad = np.empty((8, 3))
        for k in range(3):
            others = [j for j in range(3) if j != k]
            grad[:, k] = slope[:, k] * factors[:, others[0]] * factors[:, others[1]]
        for a in range(8):
            gx, gy, gz = grad[a]
            out[g, 0, 3 * a] = gx
            out[g, 1, 3 * a + 1] = gy
            out[g, 2, 3 * a + 2] = gz
            out[g, 3, 3 * a + 1], out[g, 3, 3 * a + 2] = gz, gy
            out[g, 4, 3 * a], out[g, 4, 3 * a + 2] = gz, gx
            out[g, 5, 3 * a], out[g, 5, 3 * a + 1] = gy, gx
    return out


def element_matrices(cell: np.ndarray, elasticity: np.ndarray) -> np.ndarray:
    """Stiffness matrices (e, 24, 24) float64 of boxes of edges ``cell`` (3,) mm, each with
    its own elasticity ``elasticity`` (e, 6, 6) (Voigt order, engineering shear), by
    2 x 2 x 2 Gauss points (exact for the trilinear box)."""
    b = _gauss_strains(float(cell[0]), float(cell[1]), float(cell[2]))
    volume = float(np.prod(cell)) / 8.0
    db = np.einsum("eij,gjb->egib", elasticity, b)
    out: NDArray[np.float64] = volume * np.einsum("gia,egib->eab", b, db)
    return out


def isotropic(poisson: float) -> np.ndarray:
    """The isotropic elasticity (6, 6) at E = 1."""
    return elasticity_matrix(poisson)


def rotation_6x6(theta: np.ndarray) -> np.ndarray:
    """Matrices (n, 6, 6) that turn an elasticity by ``theta`` (n,) radians about z:
    ``T D T^T`` is D's material turned by theta (stress transformation in Voigt form)."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros((len(theta), 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, -s, s, c, 1.0
    t = np.zeros((len(theta), 6, 6))
    for row, (i, j) in enumerate(_PAIRS):
        for col, (k, m) in enumerate(_PAIRS):
            value = r[:, i, k] * r[:, j, m]
            if k != m:
                value = value + r[:, i, m] * r[:, j, k]
            t[:, row, col] = value
    return t


def rotated(elasticity: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``elasticity`` (6, 6) turned about z by each of ``theta`` (n,) rad: (n, 6, 6)."""
    t = rotation_6x6(theta)
    out: NDArray[np.float64] = np.einsum("nij,jk,nlk->nil", t, elasticity, t)
    return out


def harmonics(elasticity: np.ndarray) -> np.ndarray:
    """``elasticity`` (6, 6) turned about z by theta is ``sum_m h[m] * trig_m(theta)`` with
    trig = (1, cos 2t, sin 2t, cos 4t, sin 4t): the five (5, 6, 6) terms h."""
    angles = np.arange(8) * np.pi / 8.0
    samples = rotated(elasticity, angles).reshape(8, 36)
    basis = trig(angles)  # (8, 5)
    terms, *_ = np.linalg.lstsq(basis, samples, rcond=None)
    out: NDArray[np.float64] = terms.reshape(5, 6, 6)
    return out


def trig(theta: np.ndarray) -> np.ndarray:
    """(n, 5): 1, cos 2t, sin 2t, cos 4t, sin 4t of ``theta`` (n,) rad."""
    theta = np.asarray(theta, dtype=float)
    return np.column_stack([np.ones_like(theta), np.cos(2 * theta), np.sin(2 * theta),
                            np.cos(4 * theta), np.sin(4 * theta)])


def assemble_each(mesh: HexMesh, elasticity: np.ndarray) -> sp.csr_matrix:
    """The global stiffness (3n, 3n) CSR, per unit modulus, of elements each with its own
    ``elasticity`` (e, 6, 6), built and assembled :data:`CHUNK` elements at a time."""
    n = 3 * len(mesh.points)
    dofs = mesh.dofs.astype(np.int32)
    parts: list[sp.coo_matrix] = []
    for start in range(0, len(dofs), CHUNK):
        part = dofs[start:start + CHUNK]
        ke = element_matrices(mesh.grid.cell, elasticity[start:start + CHUNK])
        rows = np.repeat(part, 24, axis=1).ravel()
        cols = np.tile(part, (1, 24)).ravel()
        parts.append(sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(n, n)).tocoo())
    rows = np.concatenate([p.row for p in parts])
    cols = np.concatenate([p.col for p in parts])
    data = np.concatenate([p.data for p in parts])
    return sp.csr_matrix((data, (rows, cols)), shape=(n, n))
