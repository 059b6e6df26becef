"""G-code a user can trust: header totals, modes, speeds, fan, retraction, resume, bodies."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import shapely
import trimesh
from support.slicer_helpers import DATA, box_stl, extrusions, write_mesh

from slicer.output.gcode import summarize
from slicer.output.gcodefile import write_gcode
from slicer.output.labels import ObjectLabels, extruding_moves
from slicer.paths.layer import WALL_INNER, WALL_OUTER
from slicer.plan import SlicePlan
from slicer.settings import SettingsError, SliceSettings


@pytest.fixture(scope="module")
def two_boxes(tmp_path_factory):
    a = trimesh.creation.box(extents=(10, 10, 5))
    b = trimesh.creation.box(extents=(10, 10, 8))
    b.apply_translation((30, 0, 0))
    path = tmp_path_factory.mktemp("two") / "two.stl"
    return write_mesh(trimesh.util.concatenate([a, b]), path)


def _words(line: str) -> dict[str, float]:
    return {w[0]: float(w[1:]) for w in line.split(";")[0].split()[1:]}


def test_header_totals_match_the_program(tmp_path) -> None:
    plan = SlicePlan.from_file(DATA / "dogbone_100x30x5.stl", SliceSettings())
    out = tmp_path / "d.gcode"
    summary = write_gcode(plan, out)
    lines = out.read_text().splitlines()
    parsed = summarize(lines, plan.settings)
    assert parsed.layers == summary.layers == plan.layer_count
    assert parsed.filament_mm == pytest.approx(summary.filament_mm, rel=1e-3)
    assert parsed.time_s == pytest.approx(summary.time_s, rel=0.03)
    assert f";LAYER_COUNT:{plan.layer_count}" in lines
    assert any(line.startswith(";TIME:") for line in lines[:20])
    assert any(line.startswith(";Filament used:") for line in lines[:20])
    assert any(line.startswith(";Filament mass:") for line in lines[:20])
    assert "M83" in lines
    grams = summary.filament_mm * plan.settings.filament_area * 1.24 / 1000
    assert summary.filament_g == pytest.approx(grams)


def test_time_model_charges_acceleration() -> None:
    from slicer.output.motion import run_time

    straight = run_time(np.array([[0.0, 0.0], [100.0, 0.0]]), 50.0, 1000.0)
    assert straight == pytest.approx(100 / 50 + 50 / 1000)
    # a polyline along the same straight line costs the same (no stop at collinear joints)
    pts = np.stack([np.linspace(0, 100, 101), np.zeros(101)], axis=1)
    assert run_time(pts, 50.0, 1000.0) == pytest.approx(straight)
    # a square slows down at each corner (to ~5.6 mm/s by junction deviation), not to rest
    square = np.array([[0, 0], [25, 0], [25, 25], [0, 25], [0, 0]], dtype=float)
    stop_each_corner = 4 * run_time(square[:2], 50.0, 1000.0)
    assert straight + 0.1 < run_time(square, 50.0, 1000.0) < stop_each_corner


def test_rest_time_is_segment_times_to_the_bit() -> None:
    """The scalar rest-to-rest time equals the vectorised one exactly (trapezoids,
    triangles, zero lengths), so layer times and the header do not change by a bit."""
    from slicer.output.motion import rest_time, segment_times

    rng = np.random.default_rng(7)
    short = long = 0
    length = np.concatenate([[0.0, 1e-12, 0.2, 0.6, 1.0, 3.0], rng.uniform(0, 50, 2000),
                             rng.uniform(0, 0.5, 2000)])
    for speed, accel in [(150.0, 1000.0), (5.0, 100.0), (25.0, 1000.0), (7.3, 10.0),
                         *zip(rng.uniform(1, 300, 20).tolist(), rng.uniform(10, 5e4, 20).tolist(),
                              strict=True)]:
        zero = np.zeros(len(length))
        expected = segment_times(length, speed, zero, zero, accel)
        got = np.array([rest_time(x, speed, accel) for x in length.tolist()])
        assert got.tobytes() == expected.tobytes()
        short += int((length < speed * speed / accel).sum())  # no cruise: a triangle
        long += int((length > speed * speed / accel).sum())
    assert short > 1000
    assert long > 1000


def test_start_and_resume_blocks() -> None:
    plan = SlicePlan.from_file(DATA / "cube20_xyz.stl", SliceSettings())
    start = plan.start_gcode()
    assert start[:4] == ["M140 S60", "M104 S210", "M190 S60", "M109 S210"]
    assert "G28" in start
    assert "M83" in start
    assert "G92 E0" in start
    cold = plan.with_settings(SliceSettings.from_mapping({"skip_heating": True}))
    assert not any(
        line.split()[0] in ("M104", "M109", "M140", "M190") for line in cold.start_gcode()
    )
    resume = plan.resume_gcode(10)
    assert "G28 X Y" in resume
    assert "M83" in resume
    assert "G92 E0" in resume
    assert f"G92 Z{plan.layer_z(9):.3f}" in resume
    lift = [line for line in resume if line.startswith("G0") and "Z" in line]
    assert lift
    assert _words(lift[0])["Z"] > plan.layer_z(9)
    assert "M109 S210" in resume
    assert not any("M109" in line for line in cold.resume_gcode(10))
    assert "G28" not in resume  # never home Z onto the part


def test_speeds_fan_and_modes() -> None:
    settings = SliceSettings.from_mapping({"fan_first_layer": 2, "first_layer_speed": 15})
    plan = SlicePlan.from_file(DATA / "cube20_xyz.stl", settings)
    first = plan.layer_gcode(0)
    feeds = {_words(line).get("F") for line in first if line.startswith("G1") and "X" in line}
    assert feeds - {None} == {900.0}
    assert "M107" in first
    assert any(line.startswith("M106") for line in plan.layer_gcode(2))
    assert not any(line.startswith("M106") for line in plan.layer_gcode(1))
    assert plan.resume_gcode(5)[-1].startswith("M106")
    later = plan.layer_gcode(10)
    assert later[0] == ";LAYER:10"
    z_moves = [line for line in later if line.startswith("G0") and "Z" in line]
    assert _words(z_moves[0])["Z"] == pytest.approx(plan.layer_z(10))


def test_retract_only_when_leaving_the_part(two_boxes) -> None:
    plan = SlicePlan.from_file(two_boxes, SliceSettings())
    r = f"G1 E{-plan.settings.retract_length:.5f}"
    # both boxes present: travels between them retract
    both = plan.layer_gcode(10)
    assert sum(line.startswith(r) for line in both) >= 2
    # one box alone: only the retraction before the layer change
    single = plan.layer_gcode(10, excluded_bodies=frozenset({1}))
    assert sum(line.startswith(r) for line in single) == 1


def test_path_spans_label_as_the_lines_read(two_boxes) -> None:
    """Each layer records its paths' lines and bodies (arcs or not, reused layers
    included): every extruding move read back from the lines lies in a span of the
    body its midpoint is in, and labelling from the spans brackets the same lines as
    labelling from reading the lines."""
    for arcs in ("off", "on"):
        plan = SlicePlan.from_file(two_boxes, SliceSettings.from_mapping({"gcode.arcs": arcs}))
        labels = ObjectLabels(plan)
        for i in range(plan.layer_count):
            code = plan.layer_code(i)
            assert code.spans is not None, i
            spans = code.spans
            assert len(spans) > 0, i
            assert set(spans[:, 2].tolist()) <= {0, 1}, i
            assert (spans[:, 0] <= spans[:, 1]).all(), i
            assert (spans[1:, 0] > spans[:-1, 1]).all(), i
            for first, last, _body in spans.tolist():
                assert all(code.lines[k][:2] == "G1" or code.lines[k][:2] in ("G2", "G3")
                           for k in range(first, last + 1)), (i, first)
            moves, points = extruding_moves(code.lines)
            span_of = np.searchsorted(spans[:, 0], moves, side="right") - 1
            assert (span_of >= 0).all(), i
            assert (moves <= spans[span_of, 1]).all(), i
            polys, bodies = plan.layer_bodies(i)
            inside = shapely.contains_xy(polys[:, None], points[None, :, 0], points[None, :, 1])
            assert (inside.sum(axis=0) == 1).all(), i
            assert np.array_equal(spans[span_of, 2], bodies[inside.argmax(axis=0)]), i
            assert labels.label_layer(i, code.lines, spans) == labels.label_layer(
                i, code.lines), i


def test_excluded_bodies_drop_one_object(two_boxes) -> None:
    plan = SlicePlan.from_file(two_boxes, SliceSettings())
    assert plan.body_count == 2
    cx = plan.bed[0] / 2
    for i in (5, 20):
        kept = plan.layer_gcode(i, excluded_bodies=frozenset({0}))
        xs = [_words(line)["X"] for line in kept if line.startswith("G1") and "X" in line]
        assert xs, i
        assert min(xs) > cx, i  # body 0 (the left box) is gone
    # above the short box only the tall one remains; excluding it leaves an empty layer
    top = plan.layer_count - 1
    assert plan.layer_gcode(top, excluded_bodies=frozenset({1})) == [f";LAYER:{top}"]


def test_wall_order_setting(tmp_path) -> None:
    path = box_stl(tmp_path / "b.stl", (15, 15, 3))
    outer = SlicePlan.from_file(path, SliceSettings())
    inner = outer.with_settings(SliceSettings.from_mapping({"wall_order": "inner_first"}))
    types = lambda lines: [line[6:] for line in lines if line.startswith(";TYPE:")]  # noqa: E731
    assert types(outer.layer_gcode(5))[:2] == [WALL_OUTER, WALL_INNER]
    assert types(inner.layer_gcode(5))[:2] == [WALL_INNER, WALL_OUTER]
    # the outer wall's seam is at the rear (max y)
    wall = extrusions(outer.layer_gcode(5), WALL_OUTER)[0]
    assert wall[0, 1] == pytest.approx(wall[:, 1].max())


def test_with_settings_keeps_geometry_and_refuses_new_layer_heights() -> None:
    plan = SlicePlan.from_file(DATA / "cube20_xyz.stl", SliceSettings())
    denser = plan.with_settings(SliceSettings.from_mapping({"infill.density": 0.5}))
    assert denser.layer_count == plan.layer_count
    assert denser.layer_gcode(50) != plan.layer_gcode(50)
    assert plan.layer_gcode(50) == plan.with_settings(plan.settings).layer_gcode(50)
    with pytest.raises(SettingsError, match="layer_height"):
        plan.with_settings(SliceSettings.from_mapping({"layer_height": 0.3}))


def test_layers_from_threads_are_identical() -> None:
    plan = SlicePlan.from_file(DATA / "bunny.stl", SliceSettings())
    layers = list(range(0, plan.layer_count, 5))
    sequential = [plan.layer_gcode(i) for i in layers]
    with ThreadPoolExecutor(max_workers=4) as pool:
        parallel = list(pool.map(plan.layer_gcode, layers * 2))
    assert parallel == sequential * 2
