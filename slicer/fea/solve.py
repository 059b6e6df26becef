"""Linear elastic analysis of a voxel mesh under a load case: loads, supports, solve, stress."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from slicer.fea.hexmesh import (
    Faces,
    HexMesh,
    boundary_faces,
    elasticity_matrix,
    element_matrix,
    strain_matrix,
)
from slicer.fea.loadcase import NORMAL_CONE_DEG, LoadCase, LoadCaseError, Region

if TYPE_CHECKING:
    import scipy.sparse as sp

RTOL = 1e-8  # relative residual at which the conjugate gradients stop
MAX_ITERATIONS = 20_000
MG_ITERATIONS = 300  # with multigrid, more than this means it does not suit the mesh


@dataclass(frozen=True)
class Solution:
    """The analysis' result.

    ``displacement`` (n, 3) float64 mm at the mesh's nodes; ``stress`` (e, 6)
    float64 MPa at element centres (xx, yy, zz, yz, xz, xy); ``von_mises`` (e,)
    float64 MPa; ``iterations`` of the solver; ``seconds`` it took; ``adjoint``
    (n, 3) float64 the displacement under the extra load asked for, if any.
    """

    mesh: HexMesh
    displacement: np.ndarray
    stress: np.ndarray
    von_mises: np.ndarray
    iterations: int
    seconds: float
    adjoint: np.ndarray | None = None


def select(faces: Faces, region: Region, cell: np.ndarray) -> np.ndarray:
    """Indices of the boundary faces a region selects: centre inside the box grown by
    half a cell along the face's own normal (the voxel surface lies within that of
    the model's surface), and with the surface's outward normal within 30 degrees
    of the region's ``normal`` if given."""
    grow = 0.5 * np.abs(faces.axis_normal) * np.asarray(cell)[None, :]
    lo, hi = region.box[0] - grow, region.box[1] + grow
    inside = np.all((faces.centre >= lo) & (faces.centre <= hi), axis=1)
    if region.normal is not None:
        cone = math.cos(math.radians(NORMAL_CONE_DEG))
        inside &= faces.smooth_normal @ region.normal >= cone
    return np.flatnonzero(inside)


def _describe_extent(points: np.ndarray) -> str:
    lo, hi = points.min(axis=0), points.max(axis=0)
    return ", ".join(f"{a} {lo[k]:g}..{hi[k]:g}" for k, a in enumerate("xyz"))


def _selected(faces: Faces, region: Region, mesh: HexMesh, case: LoadCase) -> np.ndarray:
    chosen = select(faces, region, mesh.grid.cell)
    if chosen.size == 0:
        box = region.box
        where = f"[[{box[0][0]:g}, {box[0][1]:g}, {box[0][2]:g}], " \
                f"[{box[1][0]:g}, {box[1][1]:g}, {box[1][2]:g}]]"
        facing = "" if region.normal is None else " facing its normal"
        raise LoadCaseError(
            f"{case.source}: {region.label}: box {where} selects no face of the model{facing} "
            f"(the model spans {_describe_extent(mesh.points)} mm)"
        )
    return chosen


def nodal_loads(mesh: HexMesh, faces: Faces, case: LoadCase) -> np.ndarray:
    """Forces on the nodes (n, 3) float64 N from the case's forces and pressures.

    A force is spread over its faces by area; a pressure ``p`` acts as traction
    ``-p * n`` on each face of outward normal ``n``. Each face's share goes a
    quarter to each of its four corners (exact for a constant traction on a
    bilinear face).
    """
    load = np.zeros((len(mesh.points), 3))
    for item in case.loads:
        chosen = _selected(faces, item.region, mesh, case)
        area = faces.area[chosen]
        if item.vector is not None:
            per_face = area[:, None] / area.sum() * item.vector[None, :]
        else:
            assert item.mpa is not None  # a load is a force or a pressure
            per_face = -float(item.mpa) * area[:, None] * faces.axis_normal[chosen]
        for corner in range(4):
            for comp in range(3):
                load[:, comp] += np.bincount(
                    faces.nodes[chosen, corner], weights=per_face[:, comp] / 4.0,
                    minlength=len(mesh.points),
                )
    return load


def fixed_nodes(mesh: HexMesh, faces: Faces, case: LoadCase) -> np.ndarray:
    """Nodes held in place (k,) int64; refuses a case that leaves a body free to move."""
    held = np.zeros(len(mesh.points), dtype=bool)
    for region in case.fixed:
        chosen = _selected(faces, region, mesh, case)
        held[faces.nodes[chosen].ravel()] = True
    for body in range(mesh.bodies):
        members = mesh.body == body
        nodes = np.unique(mesh.nodes[members])
        anchor = nodes[held[nodes]]
        where = _describe_extent(mesh.centres[members])
        name = "the part" if mesh.bodies == 1 else f"body {body + 1} of {mesh.bodies} ({where})"
        if anchor.size == 0:
            raise LoadCaseError(
                f"{case.source}: {name} is held by no [[fixed]] region: it is free to move "
                "along x, y and z and to turn about them"
            )
        spread = mesh.points[anchor] - mesh.points[anchor].mean(axis=0)
        rank = np.linalg.matrix_rank(spread, tol=1e-6 * float(np.abs(spread).max() or 1.0))
        if rank < 2:
            direction = np.linalg.svd(spread)[2][0] if rank == 1 else np.array([0.0, 0.0, 1.0])
            centre = mesh.points[anchor].mean(axis=0)
            raise LoadCaseError(
                f"{case.source}: {name} is held only along a line: it is free to turn about "
                f"the axis through ({centre[0]:g}, {centre[1]:g}, {centre[2]:g}) along "
                f"({direction[0]:.2f}, {direction[1]:.2f}, {direction[2]:.2f})"
            )
    return np.flatnonzero(held)


def analyse(mesh: HexMesh, case: LoadCase, modulus_scale: np.ndarray | None = None,
            adjoint: np.ndarray | None = None, elasticity: np.ndarray | None = None) -> Solution:
    """Solve ``K u = f`` for the case and recover the stress.

    ``modulus_scale`` (e,) float64 in [0, 1] multiplies each element's modulus
    (a printed part rebuilt from its roads); None means solid everywhere. The
    stiffness (one 24 x 24 matrix shared by every box, scaled) is assembled a
    chunk at a time into a sparse matrix and solved by conjugate gradients
    preconditioned with a geometric multigrid V-cycle (see
    :class:`slicer.fea.multigrid.Multigrid`): memory grows linearly with the
    mesh, with no factorisation of the whole matrix. ``adjoint`` (n, 3) float64 N:
    a second load on the same supports, solved with the same matrix and
    preconditioner (an objective's adjoint), its displacement in the answer.
    ``elasticity`` (e, 6, 6) float64: each element's own elasticity at E = 1 (an
    anisotropic box, see :mod:`slicer.fea.roadstiff`) in place of the isotropic one
    (``modulus_scale`` still multiplies it).
    Raises LoadCaseError for a case the mesh cannot carry.
    """
    from slicer.fea.multigrid import Multigrid, assemble  # scipy.sparse.linalg: when solving

    started = time.perf_counter()
    faces = boundary_faces(mesh)
    held = fixed_nodes(mesh, faces, case)
    force = nodal_loads(mesh, faces, case).ravel()
    scale = (np.ones(len(mesh.nodes)) if modulus_scale is None
             else np.asarray(modulus_scale, dtype=float))
    scale = scale * case.youngs_mpa
    n = 3 * len(mesh.points)
    free = np.ones(n, dtype=bool)
    free[(3 * held[:, None] + np.arange(3)).ravel()] = False
    if elasticity is None:
        ke = element_matrix(mesh.grid.cell, case.poisson)
        stiffness = assemble(mesh, ke, scale)[free][:, free].tocsr()
    else:
        from slicer.fea.anisotropic import assemble_each

        material = elasticity * scale[:, None, None]
        stiffness = assemble_each(mesh, material)[free][:, free].tocsr()
    if np.any(stiffness.diagonal() <= 0):
        raise LoadCaseError(f"{case.source}: part of the model carries no stiffness")
    positions = np.rint((mesh.points - mesh.grid.origin) / mesh.grid.cell).astype(np.int64)
    node_body = np.zeros(len(mesh.points), dtype=np.int64)
    node_body[mesh.nodes.ravel()] = np.repeat(mesh.body, 8)
    try:
        preconditioner = Multigrid(stiffness, positions, node_body, free)
    except RuntimeError as exc:  # a singular coarsest level: the case moves freely
        raise LoadCaseError(f"{case.source}: the model cannot carry this case ({exc})") from exc
    solve = _solver(stiffness, preconditioner, case)
    u = np.zeros(n)
    u[free], iterations = solve(force[free])
    other = None
    if adjoint is not None:
        w = np.zeros(n)
        w[free], more = solve(np.asarray(adjoint, dtype=float).ravel()[free])
        iterations += more
        other = w.reshape(-1, 3)
    dofs = mesh.dofs
    strain = u[dofs] @ strain_matrix(mesh.grid.cell).T  # (e, 6)
    if elasticity is None:
        stress = (strain @ elasticity_matrix(case.poisson).T) * scale[:, None]
    else:
        stress = np.einsum("eij,ej->ei", material, strain)
    return Solution(
        mesh=mesh,
        displacement=u.reshape(-1, 3),
        stress=stress,
        von_mises=von_mises(stress),
        iterations=iterations,
        seconds=time.perf_counter() - started,
        adjoint=other,
    )


def _solver(stiffness: sp.csr_matrix, preconditioner: Callable[[np.ndarray], np.ndarray],
            case: LoadCase) -> Callable[[np.ndarray], tuple[np.ndarray, int]]:
    """Solve ``stiffness x = rhs`` -> (x, iterations): conjugate gradients with the
    multigrid, else (a mesh the V-cycle does not suit) with Jacobi; a case that
    converges with neither is refused (LoadCaseError)."""

    def solve(rhs: np.ndarray) -> tuple[np.ndarray, int]:
        solved, iterations = conjugate_gradients(
            lambda x: stiffness @ x, rhs, preconditioner, max_iterations=MG_ITERATIONS
        )
        if solved is None:  # a mesh the smoother does not suit: plain Jacobi, slower but sure
            inverse = 1.0 / stiffness.diagonal()
            solved, more = conjugate_gradients(lambda x: stiffness @ x, rhs,
                                               lambda r: inverse * r)
            iterations += more
        if solved is None:
            raise LoadCaseError(
                f"{case.source}: the analysis did not converge in {iterations} iterations: "
                "part of the model may hang by a thread; try another mesh size"
            )
        return solved, iterations

    return solve


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    # einsum, not BLAS: a threaded BLAS spins its threads on a busy small machine
    return float(np.einsum("i,i->", a, b))


def conjugate_gradients(
    apply: Callable[[np.ndarray], np.ndarray],
    rhs: np.ndarray,
    precondition: Callable[[np.ndarray], np.ndarray],
    rtol: float = RTOL,
    max_iterations: int = MAX_ITERATIONS,
) -> tuple[np.ndarray | None, int]:
    """Solve ``K x = rhs`` for symmetric positive definite ``K`` given as ``apply``,
    with the symmetric preconditioner ``precondition`` (residual -> correction).
    ``rhs`` (n,) float64. Returns (x (n,), iterations), x None when the
    residual did not fall below ``rtol`` times the right-hand side's norm."""
    x = np.zeros_like(rhs)
    r = rhs.copy()
    z = precondition(r)
    p = z.copy()
    rz = _dot(r, z)
    goal = rtol * np.sqrt(_dot(rhs, rhs))
    if goal == 0:
        return x, 0
    for iteration in range(max_iterations):
        if np.sqrt(_dot(r, r)) <= goal:
            return x, iteration
        q = apply(p)
        curvature = _dot(p, q)
        if not curvature > 0:
            return None, iteration
        alpha = rz / curvature
        x += alpha * p
        r -= alpha * q
        z = precondition(r)
        rz, previous = _dot(r, z), rz
        p = z + (rz / previous) * p
    return None, max_iterations


def von_mises(stress: np.ndarray) -> np.ndarray:
    """Von Mises stress (e,) of stresses (e, 6) in Voigt order, same units."""
    sx, sy, sz, tyz, txz, txy = stress.T
    squared: NDArray[np.float64] = (
        0.5 * ((sx - sy) ** 2 + (sy - sz) ** 2 + (sz - sx) ** 2)
        + 3.0 * (tyz**2 + txz**2 + txy**2)
    )
    return np.sqrt(squared)
