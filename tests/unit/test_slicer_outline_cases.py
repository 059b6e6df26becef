"""Outline cases found by the benchmark corpus: flat walls cut across long triangles, and
plates of separate parts numbered without the whole-model cut."""

from __future__ import annotations

import numpy as np
import shapely
import trimesh

from slicer.input.grouping import group_rows
from slicer.input.outline import drop_collinear
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

BED = (200.0, 200.0, 200.0)


def tower_with_hole() -> trimesh.Trimesh:
    """A 6 x 6 x 40 mm tower with a round hole: every side face one long triangle pair."""
    outer = trimesh.creation.box((6.0, 6.0, 40.0))
    hole = trimesh.creation.cylinder(radius=1.5, height=50.0, sections=48)
    return outer.difference(hole, engine="manifold")


def test_equal_layers_get_equal_outlines():
    mesh = tower_with_hole()
    plan = SlicePlan.from_mesh(mesh.vertices, mesh.faces, SliceSettings(), BED)
    wkb = {shapely.to_wkb(plan.outline(i)) for i in range(5, plan.layer_count - 5)}
    assert len(wkb) == 1
    # and the points cut across diagonals are gone: the square has its 4 corners only
    poly = shapely.get_parts(plan.outline(10))[0]
    assert len(poly.exterior.coords) == 5


def test_drop_collinear_keeps_corners_and_removes_repeats():
    square = np.array([[0, 0], [1, 0], [2, 0], [2, 2], [2, 2], [0, 2], [0, 1]], dtype=float)
    tri = np.array([[5, 5], [6, 5], [5, 6]], dtype=float)
    coords, offsets = drop_collinear(np.concatenate([square, tri]), np.array([0, 7, 10]))
    assert offsets.tolist() == [0, 4, 7]
    assert coords[:4].tolist() == [[0, 0], [2, 0], [2, 2], [0, 2]]
    # a spike (going back along itself) is not a straight continuation: kept
    spike = np.array([[0, 0], [3, 0], [1, 0], [1, 1]], dtype=float)
    assert len(drop_collinear(spike, np.array([0, 4]))[0]) == 4


def test_parts_apart_are_numbered_like_the_whole_cut():
    parts = [trimesh.creation.box((10, 10, 5 + k)).apply_translation((15.0 * k, 0, (5 + k) / 2))
             for k in range(4)]
    mesh = trimesh.util.concatenate(parts)
    plan = SlicePlan.from_mesh(mesh.vertices, mesh.faces, SliceSettings(), BED)
    assert plan.body_count == 4
    # object k is the k-th part (order of first face), whatever was cut so far
    for k in range(4):
        outline = plan.outline(2, frozenset(set(range(4)) - {k}))
        assert abs(outline.centroid.x - (plan.bounds[0] + 5 + 15 * k)) < 1e-6


def test_group_rows_is_exact_and_stable():
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 6, size=(5000, 3)).astype(np.int64)
    order, first = group_rows(rows)
    groups = np.cumsum(first) - 1
    sorted_rows = rows[order]
    assert first.sum() == len(np.unique(rows, axis=0))
    assert (sorted_rows == sorted_rows[np.flatnonzero(first)][groups]).all()
    # within a group the rows keep ascending order (the first is the lowest)
    assert (np.diff(order)[~first[1:]] > 0).all()
