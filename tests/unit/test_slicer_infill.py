"""Infill and skins: density that means what it says, spacing, closed top and bottom, clipping."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from support.slicer_helpers import box_stl, extrusions

from slicer.paths.layer import FILL, SKIN, fill_distance
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


@pytest.fixture(scope="module")
def cube_path(tmp_path_factory):
    return box_stl(tmp_path_factory.mktemp("cube") / "cube.stl", (20, 20, 20))


def _plan(path, **values) -> SlicePlan:
    return SlicePlan.from_file(path, SliceSettings.from_mapping(values))


def _extruded_area(paths: list[np.ndarray], w: float) -> float:
    """Extruded cross-section area seen from above: path length x line width, mm^2."""
    return sum(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in paths) * w


@pytest.mark.parametrize("density", [0.1, 0.2, 0.35, 0.6])
def test_linear_volume_fraction_matches_density(cube_path, density) -> None:
    plan = _plan(cube_path, **{"infill.density": density})
    s = plan.settings
    ratios = []
    for i in range(20, 60, 3):  # middle layers: sparse infill only
        lines = plan.layer_gcode(i)
        assert not extrusions(lines, SKIN)
        domain = plan.outline(i).buffer(-fill_distance(s)).area
        ratios.append(_extruded_area(extrusions(lines, FILL), s.line_width) / domain)
    assert np.mean(ratios) == pytest.approx(density, rel=0.03)


def test_linear_spacing_is_line_width_over_density(cube_path) -> None:
    plan = _plan(cube_path, **{"infill.density": 0.25})
    s = plan.settings
    for i in (30, 31):
        paths = extrusions(plan.layer_gcode(i), FILL)
        # distance of every straight piece from the origin along the field gradient
        t = np.radians(s.infill_angle)
        g = np.array([np.sin(t), np.cos(t) * (-1 if i % 2 else 1)])
        levels = []
        for p in paths:
            seg = np.diff(p, axis=0)
            along = np.abs(seg @ np.array([-g[1], g[0]]))
            long = along > 1.0  # the chords, not the short joints along the wall
            levels.extend((p[:-1][long] @ g).tolist())
        levels = np.unique(np.round(levels, 3))
        gaps = np.diff(levels)
        assert np.allclose(gaps, s.line_width / 0.25, atol=0.002)


def test_skins_close_top_and_bottom(cube_path) -> None:
    plan = _plan(cube_path)
    s = plan.settings
    w = s.line_width
    n = plan.layer_count
    for i in [0, s.bottom_layers - 1, n - s.top_layers, n - 1]:
        lines = plan.layer_gcode(i)
        assert not extrusions(lines, FILL), i
        skin = shapely.union_all(
            [shapely.LineString(p).buffer(w / 2) for p in extrusions(lines, SKIN)]
        )
        domain = plan.outline(i).buffer(-fill_distance(s))
        assert skin.intersection(domain).area >= 0.97 * domain.area, i
    for i in (s.bottom_layers, n // 2, n - s.top_layers - 1):
        assert not extrusions(plan.layer_gcode(i), SKIN), i


def test_skin_under_an_overhang_ledge(tmp_path) -> None:
    import trimesh

    base = trimesh.creation.box(extents=(30, 30, 4))
    top = trimesh.creation.box(extents=(16, 16, 6))
    top.apply_translation((0, 0, 5))
    mesh = trimesh.util.concatenate([base, top])
    path = tmp_path / "step.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(mesh))
    plan = SlicePlan.from_file(path, SliceSettings())
    # the base's last layers are skin where the tower does not cover them, sparse under it
    i = 18  # z = 3.8, under the top of the base
    lines = plan.layer_gcode(i)
    skin = extrusions(lines, SKIN)
    fill = extrusions(lines, FILL)
    assert skin
    assert fill
    cx, cy = plan.bed[0] / 2, plan.bed[1] / 2
    tower = shapely.box(cx - 8, cy - 8, cx + 8, cy + 8)
    for p in fill:
        assert shapely.LineString(p).within(tower.buffer(0.5))


@pytest.mark.parametrize("model_density", [0.15, 1.0])
def test_infill_stays_inside_the_walls(model_density) -> None:
    from support.slicer_helpers import DATA

    plan = SlicePlan.from_file(
        DATA / "featuretype_mm.stl", SliceSettings.from_mapping({"infill.density": model_density})
    )
    s = plan.settings
    for i in range(0, plan.layer_count, 17):
        lines = plan.layer_gcode(i)
        # the infill domain w' grown by the joints' allowance
        domain = plan.outline(i).buffer(-fill_distance(s) + s.line_width / 2 + 1e-3)
        for kind in (FILL, SKIN):
            for p in extrusions(lines, kind):
                assert shapely.LineString(p).within(domain), (i, kind)


def test_sloped_shell_is_solid_and_small_regions_are_solid(tmp_path) -> None:
    import trimesh

    cone = trimesh.creation.cone(radius=15, height=20, sections=64)
    pillar = trimesh.creation.box(extents=(6, 6, 20))
    pillar.apply_translation((30, 0, 10))
    path = tmp_path / "cone.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(trimesh.util.concatenate([cone, pillar])))
    plan = SlicePlan.from_file(path, SliceSettings())
    s = plan.settings
    i = 30  # z = 6: the cone's wall slopes 0.75 mm per 1 mm, so a band under it is solid
    lines = plan.layer_gcode(i)
    skin = extrusions(lines, SKIN)
    fill = extrusions(lines, FILL)
    assert skin
    assert fill
    cone_centre = shapely.Point(plan.bounds[0] + 15, (plan.bounds[1] + plan.bounds[3]) / 2)
    radius = 15 * (1 - plan.layer_z(i) / 20)
    inner = radius - fill_distance(s)
    # the skin hugs the wall: the ring between the domain edge and a band inside it
    for p in skin:
        d = shapely.LineString(p).distance(cone_centre)
        if d < 25:  # skin of the cone, not of the pillar
            assert d > inner - 4 * s.layer_height / 0.75 - s.line_width
    # the 6 mm pillar's infill domain (< 70 mm^2) is filled solid at every height
    px = plan.bounds[2] - 3
    for p in fill:
        assert shapely.LineString(p).distance(shapely.Point(px, cone_centre.y)) > 4
    assert any(shapely.LineString(p).distance(shapely.Point(px, cone_centre.y)) < 3 for p in skin)


def test_skin_shared_out_to_the_islands_it_lies_in() -> None:
    """A layer's skin goes to the islands whose infill domains hold its parts, whole;
    a sliver outside every domain goes nowhere, and the result is what overlaying each
    domain with the skin gives where the parts lie inside."""
    from slicer.paths.layer import _skin_by_island

    fill = np.array([shapely.box(0, 0, 10, 10), shapely.box(20, 0, 30, 10),
                     shapely.box(40, 0, 50, 10)], dtype=object)
    inside_first = [shapely.box(1, 1, 4, 4), shapely.box(6, 6, 9, 9)]
    inside_third = [shapely.box(41, 2, 49, 8)]
    sliver = shapely.box(12, 0, 12.05, 10)  # between the first two domains
    skin = shapely.MultiPolygon([*inside_first, sliver, *inside_third])
    shared = _skin_by_island(fill, skin)
    assert shared[1] is None
    assert shapely.equals(shared[0], shapely.MultiPolygon(inside_first))
    assert shapely.equals(shared[2], shapely.MultiPolygon(inside_third))
    overlaid = shapely.intersection(fill, skin)
    assert np.allclose(shapely.area(overlaid), [18.0, 0.0, 48.0])
    assert all(shapely.equals(a, b) for a, b in zip(shared[[0, 2]], overlaid[[0, 2]], strict=True))
    # one island: the skin is its own, unchanged
    alone = _skin_by_island(fill[:1], skin)
    assert alone[0] is skin


def test_small_sparse_regions_become_skin_island_by_island() -> None:
    """Sparse regions under ``below`` mm^2 join their own island's skin (after its own
    parts, in order); an island left with no sparse region gets None; islands without a
    small region keep theirs as they were."""
    from slicer.paths.layer import _solid_small_regions

    box = shapely.box
    skin = np.array([shapely.MultiPolygon([box(0, 0, 4, 4)]), None, None,
                     shapely.MultiPolygon([box(60, 0, 62, 2)])], dtype=object)
    sparse = np.array([
        shapely.MultiPolygon([box(5, 0, 6, 1), box(10, 0, 30, 20)]),  # small and big
        shapely.MultiPolygon([box(40, 0, 41, 1), box(42, 0, 43, 2)]),  # small only
        shapely.MultiPolygon([box(50, 0, 58, 9)]),  # big only
        shapely.MultiPolygon([box(63, 0, 63.5, 0.5)]),  # small, beside its own skin
    ], dtype=object)
    new_skin, new_sparse = _solid_small_regions(skin, sparse, below=5.0)
    parts = [[tuple(np.round(shapely.bounds(p), 3)) for p in shapely.get_parts(g)]
             if g is not None else None for g in new_skin]
    assert parts[0] == [(0, 0, 4, 4), (5, 0, 6, 1)]
    assert parts[1] == [(40, 0, 41, 1), (42, 0, 43, 2)]
    assert parts[2] is None
    assert parts[3] == [(60, 0, 62, 2), (63, 0, 63.5, 0.5)]
    assert shapely.equals(new_sparse[0], box(10, 0, 30, 20))
    assert new_sparse[1] is None
    assert new_sparse[2] is sparse[2]
    assert new_sparse[3] is None
    assert skin[1] is None  # the inputs are not changed
