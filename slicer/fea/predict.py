"""What a test bench would read of printed parts: each G-code rebuilt from its roads, read."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from slicer.fea.field import analyse_arrays
from slicer.fea.gage import gage_span, pulls_along_x, spans
from slicer.fea.hexmesh import boundary_faces
from slicer.fea.loadcase import LoadCase, read_load_case
from slicer.fea.printed import apparent_modulus, fill_fractions, read_roads
from slicer.fea.roadstiff import box_elasticity
from slicer.fea.solve import Solution, analyse, nodal_loads
from slicer.settings import SliceSettings

if TYPE_CHECKING:
    from trimesh.path import Path2D


@dataclass(frozen=True)
class Prediction:
    """What a test bench would read of one specimen: ``moduli`` (MPa, nominal stress over
    the strain an extensometer reads, one per span of the :class:`TensionTest`, the
    named span first; empty when the case pulls nothing along x), ``stiffness``
    (N/mm, the total force over the load-weighted displacement of the faces it acts
    on: force over grip displacement in a tension test), ``compliance`` (f . u, N mm,
    every load of the case), the extruded ``mass_g`` (0 for the solid model) and the
    mean ``fill`` fraction of the model's boxes."""

    name: str
    moduli: tuple[float, ...]
    mass_g: float
    fill: float
    stiffness: float = float("nan")
    compliance: float = float("nan")

    @property
    def modulus_mpa(self) -> float:
        """The reading at the named gage length, MPa (NaN without a pull along x)."""
        return self.moduli[0] if self.moduli else float("nan")


@dataclass(frozen=True)
class TensionTest:
    """The test's geometry in the model frame: pull along x, extensometers ``gages``
    ((x0, x1) for each of ``spans`` mm, the named one first) over ``band`` (y0, y1),
    ``newtons`` the pull, ``area_mm2`` the nominal cross-section at mid-length,
    ``reads`` what the case names as its headline (extensometer or stiffness)."""

    spans: tuple[float, ...]
    gages: tuple[tuple[float, float], ...]
    band: tuple[float, float]
    newtons: float
    area_mm2: float
    reads: str = "extensometer"

    @property
    def gage(self) -> tuple[float, float]:
        """The named extensometer's ends (x0, x1), mm."""
        return self.gages[0]


def tension_test(vertices: np.ndarray, faces: np.ndarray, case: LoadCase) -> TensionTest:
    """The test a load case sets on a specimen along x: the pull is the x forces'
    sum; the extensometers span the case's gage length (default the paper's 20 mm),
    a longer span and the free length between the grips (``slicer.fea.gage.spans``),
    centred, over the middle third of the width; the nominal area is the model's
    cross-section at mid-length. The headline is the case's ``[test] reads``, else
    the extensometer for a pull along x and the stiffness for any other case."""
    import trimesh

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    middle = (lo + hi) / 2.0
    lengths = spans(case, lo, hi)
    gages = tuple(gage_span(lo, hi, length)[0] for length in lengths)
    band = gage_span(lo, hi, lengths[0])[1]
    newtons = sum(float(load.vector[0]) for load in case.loads if load.vector is not None)
    section = trimesh.Trimesh(vertices, faces, process=False).section(
        plane_origin=middle, plane_normal=[1.0, 0.0, 0.0])
    area = 0.0
    if section is not None:
        # trimesh annotates to_2D as Tuple["Path2D", NDArray] with its own Tuple = tuple
        # alias, which mypy reads as a bare tuple: the first item is the Path2D
        planar = cast("Path2D", section.to_2D()[0])
        area = float(planar.area)
    reads = case.reads or ("extensometer" if pulls_along_x(case) else "stiffness")
    return TensionTest(lengths, gages, band, newtons, abs(area), reads)


def measured(solution: Solution, test: TensionTest) -> float:
    """The apparent modulus at the named gage length of a solved test, MPa (NaN
    without a pull along x)."""
    readings = moduli(solution, test)
    return readings[0] if readings else float("nan")


def moduli(solution: Solution, test: TensionTest) -> tuple[float, ...]:
    """The apparent modulus at each of the test's spans, MPa (empty without a pull)."""
    if not test.newtons or not test.area_mm2:
        return ()
    return tuple(apparent_modulus(solution.mesh.points, solution.displacement, gage, test.band,
                                  test.newtons, test.area_mm2) for gage in test.gages)


def whole_part(solution: Solution, case: LoadCase) -> tuple[float, float]:
    """(stiffness N/mm, compliance N mm) of a solved case: the stiffness is the total
    force over the displacement of the faces it acts on along it, weighted by how the
    force is spread (pressures, such as a grip's clamping, left out); the compliance
    is every load's work ``f . u``."""
    mesh = solution.mesh
    faces = boundary_faces(mesh)
    every = nodal_loads(mesh, faces, case)
    forces = dataclasses.replace(case, loads=tuple(x for x in case.loads if x.vector is not None))
    pulled = nodal_loads(mesh, faces, forces) if forces.loads else np.zeros_like(every)
    total = float(np.sum(pulled.sum(axis=0) ** 2))
    work = float(np.sum(pulled * solution.displacement))
    stiffness = total / work if work > 0 else float("nan")
    return stiffness, float(np.sum(every * solution.displacement))


def predict_moduli(
    model: str | os.PathLike[str],
    load: str | os.PathLike[str],
    settings: SliceSettings,
    bounds: tuple[float, float, float, float],
    gcodes: dict[str, Path],
) -> list[Prediction]:
    """What a test bench would read of the solid model and of each G-code's print.

    ``bounds`` is where the slicer placed the model on the bed (its xy box), so
    the roads can be taken back to the model frame. Every print is analysed on
    the solid model's own mesh, each box with the elasticity its roads give it
    (fill and direction, :mod:`slicer.fea.roadstiff`); the masses use the
    settings' filament density.
    """
    from slicer.input.mesh import read_stl
    from slicer.output.gcode import filament_grams

    vertices, faces = read_stl(model)
    case = read_load_case(load, settings.fea_youngs_modulus_mpa, settings.fea_poisson_ratio)
    solid = analyse_arrays(vertices, faces, case, settings.fea_mesh_size)
    test = tension_test(vertices, faces, case)
    mesh = solid.mesh
    out = [Prediction("Solid", moduli(solid, test), 0.0, 1.0, *whole_part(solid, case))]
    shift = np.array([vertices[:, 0].min() - bounds[0], vertices[:, 1].min() - bounds[1],
                      vertices[:, 2].min()])
    for name, path in gcodes.items():
        lines = Path(path).read_text(encoding="ascii").splitlines()
        roads = read_roads(lines, settings.filament_diameter)
        fractions = fill_fractions(roads, mesh.grid, shift)
        elasticity = box_elasticity(roads, mesh.grid, shift, case.poisson, mesh.cells)
        solution = analyse(mesh, case, elasticity=elasticity)
        volume = float(np.sum(np.hypot(*(roads.ends[:, 1] - roads.ends[:, 0]).T)
                              * roads.width * roads.height))
        grams = filament_grams(volume / settings.filament_area, settings)
        out.append(Prediction(name, moduli(solution, test), grams,
                              float(fractions[mesh.grid.solid].mean()),
                              *whole_part(solution, case)))
    return out
