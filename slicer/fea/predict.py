"""Predicted tension-test moduli of printed parts: each G-code rebuilt, loaded, measured."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from slicer.fea.field import analyse_arrays
from slicer.fea.gage import gage_span
from slicer.fea.loadcase import LoadCase, read_load_case
from slicer.fea.optimal import strain_energy
from slicer.fea.printed import apparent_modulus, fill_fractions, modulus_scale, read_roads
from slicer.fea.solve import Solution, analyse
from slicer.settings import SliceSettings

if TYPE_CHECKING:
    from trimesh.path import Path2D


@dataclass(frozen=True)
class Prediction:
    """One specimen's predicted ``modulus_mpa`` (apparent, nominal stress over gage
    strain; NaN when the case pulls nothing along x), ``compliance`` (f . u, N mm:
    lower is stiffer, for any load case), its extruded ``mass_g`` (0 for the solid
    model) and mean ``fill`` fraction of the model's boxes."""

    name: str
    modulus_mpa: float
    mass_g: float
    fill: float
    compliance: float = float("nan")


@dataclass(frozen=True)
class TensionTest:
    """The test's geometry in the model frame: pull along x, extensometer ``gage``
    (x0, x1) over ``band`` (y0, y1), ``newtons`` the pull, ``area_mm2`` the nominal
    cross-section at mid-length."""

    gage: tuple[float, float]
    band: tuple[float, float]
    newtons: float
    area_mm2: float


def tension_test(vertices: np.ndarray, faces: np.ndarray, case: LoadCase) -> TensionTest:
    """The test a load case sets on a specimen along x: the pull is the x forces'
    sum; the extensometer spans the middle fifth of the length (``slicer.fea.gage``) over
    the middle third of the width (the paper's 10 x 20 mm gage on its dogbone);
    the nominal area is the model's cross-section at mid-length."""
    import trimesh

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    middle = (lo + hi) / 2.0
    gage, band = gage_span(lo, hi)
    newtons = sum(float(load.vector[0]) for load in case.loads if load.vector is not None)
    section = trimesh.Trimesh(vertices, faces, process=False).section(
        plane_origin=middle, plane_normal=[1.0, 0.0, 0.0])
    area = 0.0
    if section is not None:
        # trimesh annotates to_2D as Tuple["Path2D", NDArray] with its own Tuple = tuple
        # alias, which mypy reads as a bare tuple: the first item is the Path2D
        planar = cast("Path2D", section.to_2D()[0])
        area = float(planar.area)
    return TensionTest(gage, band, newtons, abs(area))


def measured(solution: Solution, test: TensionTest) -> float:
    """The apparent modulus of a solved test, MPa (NaN without a pull along x)."""
    if not test.newtons or not test.area_mm2:
        return float("nan")
    return apparent_modulus(solution.mesh.points, solution.displacement, test.gage, test.band,
                            test.newtons, test.area_mm2)


def predict_moduli(
    model: str | os.PathLike[str],
    load: str | os.PathLike[str],
    settings: SliceSettings,
    bounds: tuple[float, float, float, float],
    gcodes: dict[str, Path],
) -> list[Prediction]:
    """The solid model's modulus and each G-code's, in the load case's tension test.

    ``bounds`` is where the slicer placed the model on the bed (its xy box), so
    the roads can be taken back to the model frame. Every print is analysed on
    the solid model's own mesh, each box at the stiffness its roads fill.
    """
    from slicer.gcode import filament_grams
    from slicer.mesh import read_stl

    vertices, faces = read_stl(model)
    case = read_load_case(load, settings.fea_youngs_modulus_mpa, settings.fea_poisson_ratio)
    solid = analyse_arrays(vertices, faces, case, settings.fea_mesh_size)
    test = tension_test(vertices, faces, case)
    mesh = solid.mesh
    ones = np.ones(len(mesh.cells))
    out = [Prediction("Solid", measured(solid, test), 0.0, 1.0,
                      2.0 * float(strain_energy(solid, case, ones).sum()))]
    shift = np.array([vertices[:, 0].min() - bounds[0], vertices[:, 1].min() - bounds[1],
                      vertices[:, 2].min()])
    for name, path in gcodes.items():
        lines = Path(path).read_text(encoding="ascii").splitlines()
        roads = read_roads(lines, settings.filament_diameter)
        fractions = fill_fractions(roads, mesh.grid, shift)
        scale = modulus_scale(fractions, mesh.cells)
        solution = analyse(mesh, case, scale)
        volume = float(np.sum(np.hypot(*(roads.ends[:, 1] - roads.ends[:, 0]).T)
                              * roads.width * roads.height))
        grams = filament_grams(volume / settings.filament_area, settings)
        out.append(Prediction(name, measured(solution, test), grams,
                               float(fractions[mesh.grid.solid].mean()),
                               2.0 * float(strain_energy(solution, case, scale).sum())))
    return out


