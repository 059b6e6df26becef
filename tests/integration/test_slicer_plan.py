"""SlicePlan end to end: layer addressability, determinism, geometry of walls, holes."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh
from support.slicer_helpers import DATA, box_stl, extrusions, layer_blocks

from slicer.output.gcodefile import write_gcode
from slicer.paths.layer import WALL_OUTER
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

SETTINGS = SliceSettings()


@pytest.fixture(scope="module")
def feature_plan() -> SlicePlan:
    return SlicePlan.from_file(DATA / "featuretype_mm.stl", SETTINGS)


def test_layer_alone_equals_layer_of_full_run(feature_plan: SlicePlan, tmp_path) -> None:
    out = tmp_path / "f.gcode"
    write_gcode(feature_plan, out)
    blocks = layer_blocks(out.read_text().splitlines())
    assert sorted(blocks) == list(range(feature_plan.layer_count))
    fresh = SlicePlan.from_file(DATA / "featuretype_mm.stl", SETTINGS)
    for i in (0, 1, 7, feature_plan.layer_count // 2, feature_plan.layer_count - 1):
        assert fresh.layer_gcode(i) == blocks[i]


def test_same_input_same_bytes(tmp_path) -> None:
    a = SlicePlan.from_file(DATA / "bunny.stl", SETTINGS)
    write_gcode(a, tmp_path / "a.gcode")
    blocks = layer_blocks((tmp_path / "a.gcode").read_text().splitlines())
    # a second plan of the same file, its layers asked for in reverse order, every third
    b = SlicePlan.from_file(DATA / "bunny.stl", SETTINGS)
    for i in reversed(range(0, b.layer_count, 3)):
        assert b.layer_gcode(i) == blocks[i], f"layer {i}"
    # and what surrounds the layers too: a whole file twice is the same file
    for name in ("c.gcode", "d.gcode"):
        write_gcode(SlicePlan.from_file(DATA / "cube20_xyz.stl", SETTINGS), tmp_path / name)
    assert (tmp_path / "c.gcode").read_bytes() == (tmp_path / "d.gcode").read_bytes()


def test_outer_wall_is_the_outline_offset_by_half_a_line(tmp_path) -> None:
    plan = SlicePlan.from_file(box_stl(tmp_path / "box.stl", (20, 20, 6)), SETTINGS)
    w = SETTINGS.line_width
    cx, cy = plan.bed[0] / 2, plan.bed[1] / 2
    expected = shapely.box(cx - 10 + w / 2, cy - 10 + w / 2, cx + 10 - w / 2, cy + 10 - w / 2)
    for i in (0, 5, plan.layer_count - 1):
        walls = extrusions(plan.layer_gcode(i), WALL_OUTER)
        assert len(walls) == 1
        ring = shapely.LineString(walls[0])
        assert shapely.hausdorff_distance(ring, expected.exterior) <= 0.05


THIN = SliceSettings.from_mapping({"line_width": 0.4, "perimeters": 2})


def _tube_plan(thickness: float) -> SlicePlan:
    tube = trimesh.creation.annulus(r_min=5.0, r_max=5.0 + thickness, height=2.0, sections=96)
    return SlicePlan.from_mesh(tube.vertices, tube.faces, THIN)


def _off_level(plan: SlicePlan, ring: np.ndarray, inset: float) -> float:
    """How far a wall ring lies from the outline's level set at ``inset`` mm, mm."""
    level = shapely.boundary(shapely.buffer(plan.outline(5), -inset, quad_segs=12))
    return float(shapely.distance(shapely.points(ring), level).max())


@pytest.mark.parametrize("thickness", [1.0, 0.9, 1.08, 0.7, 0.6])
def test_thin_wall_outer_lines_widen_to_meet(thickness: float) -> None:
    # two 0.4 mm lines in a wall 0.8-1.1 mm thick would leave a gap between them, and
    # overlap in one 0.6-0.8 mm thick: the outer wall takes half the thickness and
    # its two sides meet
    plan = _tube_plan(thickness)
    paths = plan.layer_toolpaths(5)
    outer = [p for p in paths if p.kind == WALL_OUTER]
    assert len(outer) == 2
    assert all(p.kind == WALL_OUTER for p in paths if p.kind.startswith("WALL"))
    for p in outer:
        assert p.width == pytest.approx(thickness / 2.0, abs=0.02)
    for p in outer:
        assert _off_level(plan, p.coords, thickness / 4.0) < 0.03


def test_thin_wall_extrudes_for_its_width() -> None:
    plan = _tube_plan(1.0)
    paths = plan.layer_toolpaths(5)
    assert {p.kind for p in paths} == {WALL_OUTER}  # nothing else fits in 1 mm
    width = paths[0].width
    length = sum(float(np.hypot(*np.diff(p.coords, axis=0).T).sum()) for p in paths)
    code = plan.layer_code(5)
    expected = length * width * plan.layer_height(5) / THIN.filament_area
    # the line budget's chords are a little shorter than the level set's polyline
    assert code.filament_mm == pytest.approx(expected, rel=3e-3)


@pytest.mark.parametrize("thickness", [1.15, 1.2, 1.3, 1.6, 3.0])
def test_walls_keep_the_line_width_outside_the_thin_range(thickness: float) -> None:
    plan = _tube_plan(thickness)
    outer = [p for p in plan.layer_toolpaths(5) if p.kind == WALL_OUTER]
    assert len(outer) == 2
    assert all(p.width is None for p in outer)
    for p in outer:
        assert _off_level(plan, p.coords, 0.2) < 0.03


def test_cube20_outer_wall_within_005_of_offset_outline() -> None:
    plan = SlicePlan.from_file(DATA / "cube20_xyz.stl", SETTINGS)
    w = SETTINGS.line_width
    for i in range(0, plan.layer_count, 9):
        offset = plan.outline(i).buffer(-w / 2)
        walls = extrusions(plan.layer_gcode(i), WALL_OUTER)
        rings = shapely.multilinestrings([shapely.LineString(p) for p in walls])
        expected = shapely.boundary(offset)
        assert shapely.hausdorff_distance(rings, expected) <= 0.05, i


def test_holes_survive(feature_plan: SlicePlan) -> None:
    i = feature_plan.layer_count // 2
    outline = feature_plan.outline(i)
    holes = sum(len(p.interiors) for p in shapely.get_parts(outline))
    assert holes >= 2
    walls = extrusions(feature_plan.layer_gcode(i), WALL_OUTER)
    # one outer wall per exterior ring and per hole
    rings = sum(
        1 + len(p.interiors) for p in shapely.get_parts(outline.buffer(-SETTINGS.line_width / 2))
    )
    assert len(walls) == rings
    # no extrusion inside a hole
    for poly in shapely.get_parts(outline):
        for hole in poly.interiors:
            inner = shapely.Polygon(hole).buffer(-0.05)
            for path in walls:
                assert not shapely.LineString(path).intersects(inner)


def test_layer_heights_and_count(tmp_path) -> None:
    plan = SlicePlan.from_file(box_stl(tmp_path / "b.stl", (10, 10, 4)), SETTINGS)
    assert plan.layer_count == 20
    assert plan.layer_z(0) == pytest.approx(0.2)
    assert plan.layer_z(19) == pytest.approx(4.0)
    assert plan.layer_gcode(3)[0] == ";LAYER:3"
    with pytest.raises(IndexError):
        plan.layer_gcode(20)


def test_model_is_centred_on_the_bed(tmp_path) -> None:
    plan = SlicePlan.from_file(
        box_stl(tmp_path / "b.stl", (30, 10, 2)), SETTINGS, bed=(200, 180, 100)
    )
    xmin, ymin, xmax, ymax = plan.bounds
    assert (xmin + xmax) / 2 == pytest.approx(100)
    assert (ymin + ymax) / 2 == pytest.approx(90)
    assert np.isclose(xmax - xmin, 30)
