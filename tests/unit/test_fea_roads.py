"""Stiffness from the printed roads: anisotropic boxes against the roads resolved in the mesh."""

from __future__ import annotations

import numpy as np

from slicer.fea.anisotropic import element_matrices, isotropic, rotated
from slicer.fea.coupon import Coupon, fill_modulus, homogenised_modulus, resolved_modulus
from slicer.fea.hexmesh import element_matrix
from slicer.fea.roadcell import crossed_roads

E = 2200.0


def test_an_isotropic_box_built_by_gauss_points_is_the_scikit_fem_box() -> None:
    cell = np.array([0.85, 0.86, 0.83])
    mine = element_matrices(cell, isotropic(0.35)[None])[0]
    assert np.allclose(mine, element_matrix(cell, 0.35), atol=1e-12)


def test_crossed_roads_are_stiff_along_them_and_soft_across_the_diagonal() -> None:
    solid = crossed_roads(1.0, 0.44, 0.35)
    assert np.allclose(solid, isotropic(0.35), atol=1e-9)  # a full cell is the solid itself
    lattice = crossed_roads(0.4, 0.44, 0.35)
    along = 1.0 / np.linalg.inv(lattice)[0, 0]
    diagonal = 1.0 / np.linalg.inv(rotated(lattice, np.array([np.pi / 4]))[0])[0, 0]
    # half the roads run along x: about fill / 2 of E, a little more through the bonds
    assert 0.45 * 0.4 < along < 0.7 * 0.4
    # pulled at 45 degrees the roads turn like scissors held by their bonds only
    assert diagonal < 0.35 * 0.4


def test_a_solid_print_predicts_the_modulus_within_2_percent() -> None:
    coupon = Coupon(fill=1.0, wall=True)
    assert abs(homogenised_modulus(coupon, E) / E - 1.0) < 0.02


def test_a_pm45_lattice_at_40_percent_is_within_10_percent_of_its_resolved_roads() -> None:
    coupon = Coupon(fill=0.4, angle=45.0)
    resolved = resolved_modulus(coupon, E, size=0.1)
    homogenised = homogenised_modulus(coupon, E)
    assert abs(homogenised / resolved - 1.0) < 0.10, (homogenised, resolved)
    # the rule of mixtures (E times the fill, blind to direction) is far off
    assert fill_modulus(coupon, E) > 2.5 * resolved
