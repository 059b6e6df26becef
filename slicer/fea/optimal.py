"""Infill density where the strain energy is: optimality-criteria updates at equal volume."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slicer.fea.hexmesh import HexMesh, element_matrix
from slicer.fea.loadcase import LoadCase
from slicer.fea.solve import Solution, analyse

ITERATIONS = 5  # analyses after the first (each one solve)
MOVE = 0.2  # largest change of a box's density per update
FLOOR = 0.05  # least density, as the stress field's floor
DAMPING = 0.5  # the criterion's exponent


def strain_energy(solution: Solution, case: LoadCase, density: np.ndarray) -> np.ndarray:
    """Strain energy of each element, N mm: (e,) float64, for moduli ``E * density``."""
    mesh = solution.mesh
    ke = element_matrix(mesh.grid.cell, case.poisson)
    u = solution.displacement.ravel()[mesh.dofs]  # (e, 24)
    energy: NDArray[np.float64] = (
        0.5 * case.youngs_mpa * density * np.einsum("ei,ij,ej->e", u, ke, u)
    )
    return energy


def optimal_density(
    mesh: HexMesh, case: LoadCase, volume: float, iterations: int = ITERATIONS
) -> tuple[np.ndarray, list[float]]:
    """A density (e,) in [FLOOR, 1] with mean ``volume`` that makes the part stiff.

    The stiffness of a box is taken as ``E * density`` (the rule of mixtures the
    rebuilt prints use). Minimising the compliance ``f . u`` at a fixed total
    then asks for the strain energy per unit density to be even: each update
    multiplies a box's density by ``(energy / (lambda * density)) ** 0.5``
    (moved at most ``MOVE``, kept in ``[FLOOR, 1]``), ``lambda`` found by
    bisection so that the mean stays ``volume``. Returns the density and the
    compliance (N mm) of each analysis, the uniform start first.
    """
    density = np.full(len(mesh.cells), float(volume))
    compliance: list[float] = []
    for step in range(iterations + 1):
        solution = analyse(mesh, case, density)
        energy = strain_energy(solution, case, density)
        compliance.append(2.0 * float(energy.sum()))
        if step == iterations:
            break
        want = energy / density  # half the compliance's sensitivity, >= 0
        low, high = 1e-12, float(want.max()) * 1e6 + 1e-12
        for _ in range(60):
            lam = np.sqrt(low * high)
            trial = np.clip(density * (want / lam) ** DAMPING,
                            np.maximum(FLOOR, density - MOVE), np.minimum(1.0, density + MOVE))
            if trial.mean() > volume:
                low = lam
            else:
                high = lam
        density = trial
    return density, compliance
