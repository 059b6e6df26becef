"""The built-in analysis against beam theory: a bar in tension, a cantilever, voxel volumes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from slicer.fea.field import analyse_arrays, lattice_points, nodal_lattice
from slicer.fea.hexmesh import hex_mesh
from slicer.fea.loadcase import parse_load_case
from slicer.fea.voxel import default_cell, mesh_volume, voxelize

E, NU = 2200.0, 0.35


def box(length: float, width: float, height: float) -> trimesh.Trimesh:
    """A box with its least corner at the origin."""
    mesh = trimesh.creation.box((length, width, height))
    mesh.apply_translation([length / 2, width / 2, height / 2])
    return mesh


def end_loaded(length: float, width: float, height: float, newtons: list[float]) -> str:
    """A case holding the x = 0 end and loading the x = length end."""
    return f"""
[material]
youngs_modulus_mpa = {E}
poisson_ratio = {NU}
[[fixed]]
box = [[0, 0, 0], [0, {width}, {height}]]
[[force]]
box = [[{length}, 0, 0], [{length}, {width}, {height}]]
newtons = {newtons}
"""


def test_voxels_hold_the_volume_of_a_sphere() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    grid = voxelize(sphere.vertices, sphere.faces, 0.5)
    volume = grid.solid.sum() * np.prod(grid.cell)
    assert volume == pytest.approx(sphere.volume, rel=0.02)
    assert np.allclose(grid.origin, sphere.vertices.min(axis=0))


def test_a_bar_in_tension_carries_force_over_area() -> None:
    length, width, height, force = 60.0, 8.0, 5.0, 1000.0
    bar = box(length, width, height)
    case = parse_load_case(end_loaded(length, width, height, [force, 0, 0]))
    solution = analyse_arrays(bar.vertices, bar.faces, case)
    middle = np.abs(solution.mesh.centres[:, 0] - length / 2) < 5.0
    expected = force / (width * height)
    assert np.mean(solution.stress[middle, 0]) == pytest.approx(expected, rel=0.02)
    assert np.max(np.abs(solution.von_mises[middle] - expected)) < 0.02 * expected
    # elongation of the middle part: strain F / (A E)
    points, u = solution.mesh.points, solution.displacement
    planes = np.unique(np.round(points[:, 0], 9))
    x0, x1 = (planes[np.argmin(np.abs(planes - x))] for x in (20.0, 40.0))
    at = [np.abs(points[:, 0] - x) < 1e-6 for x in (x0, x1)]
    stretch = np.mean(u[at[1], 0]) - np.mean(u[at[0], 0])
    assert stretch / (x1 - x0) == pytest.approx(expected / E, rel=0.02)


def test_a_cantilever_bends_as_beam_theory_says_at_the_default_mesh() -> None:
    length, width, height, force = 100.0, 10.0, 10.0, 10.0
    beam = box(length, width, height)
    case = parse_load_case(end_loaded(length, width, height, [0, 0, -force]))
    solution = analyse_arrays(beam.vertices, beam.faces, case)
    tip = solution.mesh.points[:, 0] > length - 1e-6
    deflection = -np.mean(solution.displacement[tip, 2])
    inertia = width * height**3 / 12.0
    shear = E / (2.0 * (1.0 + NU))
    timoshenko = force * length**3 / (3 * E * inertia) + force * length / (
        5.0 / 6.0 * shear * width * height
    )
    assert deflection == pytest.approx(timoshenko, rel=0.05)
    assert solution.mesh.grid.cell[0] == pytest.approx(default_cell(mesh_volume(
        beam.vertices, beam.faces)), rel=0.05)


def test_bodies_joined_only_along_an_edge_get_their_own_nodes() -> None:
    solid = np.zeros((2, 2, 1), dtype=bool)
    solid[0, 0, 0] = solid[1, 1, 0] = True
    from slicer.fea.voxel import VoxelGrid

    mesh = hex_mesh(VoxelGrid(np.zeros(3), np.ones(3), solid))
    assert mesh.bodies == 2
    assert len(mesh.points) == 16  # 8 each: the shared edge is not shared


def test_the_nodal_field_fills_the_whole_lattice_with_the_model_corner_first() -> None:
    bar = box(30.0, 6.0, 4.0)
    bar.apply_translation([5.0, -2.0, 1.0])
    case = parse_load_case(end_loaded(35.0, 4.0, 5.0, [100, 0, 0]).replace(
        "[0, 0, 0], [0,", "[5, -2, 1], [5,").replace("[35.0, 0, 0]", "[35.0, -2, 1]"))
    solution = analyse_arrays(bar.vertices, bar.faces, case, size=1.0)
    lattice = nodal_lattice(solution)
    points = lattice_points(solution)
    assert lattice.size == len(points)
    assert np.all(np.isfinite(lattice))
    assert lattice.min() >= 0
    assert np.allclose(points.min(axis=0), [5.0, -2.0, 1.0])
