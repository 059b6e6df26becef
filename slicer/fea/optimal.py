"""Infill density where the test needs it: optimality-criteria updates at equal volume."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slicer.fea.gage import extensometer, gage_length, gage_span, pulls_along_x
from slicer.fea.hexmesh import HexMesh, element_matrix
from slicer.fea.loadcase import LoadCase
from slicer.fea.solve import Solution, analyse

ITERATIONS = 5  # updates (each one analysis, with its adjoint)
MOVE = 0.2  # largest change of a box's density per update
FLOOR = 0.05  # least density, as the stress field's floor
SECONDARY = 0.1  # weight of the whole part's compliance beside a tension test's gage reading
DAMPING = 0.5  # the criterion's exponent
OBJECTIVE_VERSION = "gage-4"  # part of the cache key: bump when the objective changes


def strain_energy(solution: Solution, case: LoadCase, density: np.ndarray) -> np.ndarray:
    """Strain energy of each element, N mm: (e,) float64, for moduli ``E * density``."""
    mesh = solution.mesh
    ke = element_matrix(mesh.grid.cell, case.poisson)
    u = solution.displacement.ravel()[mesh.dofs]  # (e, 24)
    energy: NDArray[np.float64] = (
        0.5 * case.youngs_mpa * density * np.einsum("ei,ij,ej->e", u, ke, u)
    )
    return energy


def objective_load(mesh: HexMesh, case: LoadCase) -> np.ndarray | None:
    """The reading the optimum makes small, as weights (n, 3) on the nodes'
    displacements: for a tension test along x (:func:`slicer.fea.gage.pulls_along_x`)
    the extensometer's extension of the gage (signed so that a pull reads positive),
    which the apparent modulus divides; otherwise None, meaning the compliance
    ``f . u`` (the work of the case's own loads: the load points' deflection)."""
    if not pulls_along_x(case) or case.reads == "stiffness":
        return None
    grid = mesh.grid
    lo, hi = grid.origin, grid.origin + grid.cell * np.array(grid.solid.shape)
    gage, band = gage_span(lo, hi, gage_length(case, lo, hi))
    weights, _ = extensometer(mesh.points, gage, band)
    pull = sum(float(load.vector[0]) for load in case.loads if load.vector is not None)
    signed: NDArray[np.float64] = np.sign(pull) * weights
    return signed


def objective_text(case: LoadCase, length: float) -> str:
    """What :func:`optimal_density` makes small for ``case``, in words (``length`` mm the
    extensometer's span, as :func:`slicer.fea.gage.gage_length` gives it)."""
    if not pulls_along_x(case) or case.reads == "stiffness":
        return "the whole part's compliance (force times its point's displacement)"
    return (f"the extension of a {length:g} mm extensometer, plus {SECONDARY:g} of the "
            "whole part's compliance")


def optimal_density(
    mesh: HexMesh, case: LoadCase, volume: float, iterations: int = ITERATIONS
) -> tuple[np.ndarray, list[float]]:
    """A density (e,) in [FLOOR, 1] with mean ``volume`` that makes the test's reading
    small (:func:`objective_load`: the gage's extension in a tension test, else the
    compliance), i.e. the part stiff where the test looks.

    The stiffness of a box is ``E * density`` (the rule of mixtures the rebuilt
    prints use). The reading is ``J = l . u`` with ``K u = f``; with the adjoint
    ``K w = l`` its sensitivity is ``dJ/d rho_e = -w_e . k_e u_e`` (``k_e`` the
    box's matrix at full density; for the compliance ``l = f`` and ``w = u``). Each
    update multiplies a box's density by ``(-dJ/d rho_e / lambda) ** 0.5`` (moved
    at most ``MOVE``, kept in ``[FLOOR, 1]``; a box whose material would raise the
    reading shrinks as fast as allowed), ``lambda`` found by bisection so that the
    mean stays ``volume``. Returns the density and the reading of each analysis
    (mm of extension, or N mm of compliance), the uniform start first.
    """
    load = objective_load(mesh, case)
    ke = element_matrix(mesh.grid.cell, case.poisson)
    density = np.full(len(mesh.cells), float(volume))
    readings: list[float] = []
    scales = (1.0, 1.0)
    for step in range(iterations + 1):
        solution = analyse(mesh, case, density, adjoint=load)
        u = solution.displacement.ravel()[mesh.dofs]  # (e, 24)
        energy = strain_energy(solution, case, density)
        compliance = 2.0 * float(energy.sum())
        own = 2.0 * energy / density  # -d compliance / d rho
        if solution.adjoint is None:
            readings.append(compliance)
            gain = own
        else:
            assert load is not None
            w = solution.adjoint.ravel()[mesh.dofs]
            readings.append(float(np.sum(load * solution.displacement)))
            if step == 0:
                scales = (readings[0], compliance)
            gain = (case.youngs_mpa * np.einsum("ei,ij,ej->e", w, ke, u) / scales[0]
                    + SECONDARY * own / scales[1])
        if step == iterations:
            break
        want = np.maximum(gain, 1e-12 * float(np.abs(gain).max() or 1.0))
        low, high = 1e-30, float(want.max() / FLOOR) * 1e6 + 1e-30
        trial = density
        for _ in range(80):
            lam = np.sqrt(low * high)
            trial = np.clip(density * (want / lam) ** DAMPING,
                            np.maximum(FLOOR, density - MOVE), np.minimum(1.0, density + MOVE))
            if trial.mean() > volume:
                low = lam
            else:
                high = lam
        density = trial
    return density, readings
