"""The line budget: simplification within the resolution, arcs, the wire-aware coarsening."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import shapely
import trimesh

from bench import gcodeparse
from slicer.fields.base import LayerContext, get_field
from slicer.fields.wave import mean_stretch
from slicer.output.budget import OUTER_ARC, OUTER_LINES, OUTER_LOOP, budget_moves, line_rate
from slicer.output.gcode import _pack
from slicer.paths.arcs import for_printer
from slicer.plan import SlicePlan
from slicer.settings import SettingsError, SliceSettings

_ARC = re.compile(r"^G([23]) (?:F\d+ )?X(\S+) Y(\S+) I(\S+) J(\S+) E(\S+)$")
_MOVE = re.compile(r"^G[0123] (?:F\d+ )?X(\S+) Y(\S+)")


def _plan(**values) -> SlicePlan:
    mesh = trimesh.creation.cylinder(radius=12.0, height=3.0, sections=256)
    settings = SliceSettings.from_mapping({"infill.field": "wave", **values})
    return SlicePlan.from_mesh(mesh.vertices, mesh.faces, settings)


def _moves(plan: SlicePlan, i: int):
    paths = plan.layer_toolpaths(i)
    pts, starts, ends = _pack([p.coords for p in paths])
    speeds = np.full(len(paths), plan.settings.print_speed)
    loose = np.array([p.kind == "FILL" for p in paths])
    exact = np.array([p.kind == "WALL-OUTER" for p in paths])
    return paths, budget_moves(pts, starts, ends, speeds, plan.settings, loose, exact)


def test_walls_stay_within_the_resolution_of_the_level_set() -> None:
    plan = _plan(**{"gcode.arcs": "off"})
    tol = plan.settings.resolution
    paths, mv = _moves(plan, 5)
    assert len(mv.pts) < 0.7 * sum(len(p.coords) for p in paths)  # it does drop points
    for k, path in enumerate(paths):
        if not path.kind.startswith("WALL"):
            continue
        exact = shapely.linestrings(path.coords)
        simple = shapely.linestrings(mv.pts[mv.starts[k] : mv.ends[k]])
        assert shapely.hausdorff_distance(exact, simple, densify=0.05) <= tol + 1e-9
        assert np.array_equal(simple.coords[0], path.coords[0])  # seams stay put


def test_a_long_outer_wall_keeps_closer_to_its_curve_than_a_short_one() -> None:
    settings = SliceSettings.from_mapping({"gcode.arcs": "off"})
    tol = settings.resolution

    def loop(radius: float, sections: int) -> np.ndarray:
        a = np.linspace(0.0, 2.0 * np.pi, sections + 1)
        return np.column_stack([radius * np.cos(a), radius * np.sin(a)])

    # a 128-gon of 19 mm: two sides make a chord 0.023 mm inside, more than 0.6 x 0.025
    big, small = loop(19.0, 128), loop(1.4, 40)  # 119 mm and 8.8 mm around
    assert shapely.length(shapely.linestrings(small)) < OUTER_LOOP
    pts, starts, ends = _pack([big, small])
    speeds = np.full(2, 40.0)

    def kept(exact: bool) -> list[np.ndarray]:
        mv = budget_moves(pts, starts, ends, speeds, settings, exact=np.array([exact] * 2))
        return [mv.pts[mv.starts[k] : mv.ends[k]] for k in range(2)]

    (big_outer, small_outer), (big_inner, small_inner) = kept(True), kept(False)
    off = shapely.hausdorff_distance(shapely.linestrings(big), shapely.linestrings(big_outer),
                                     densify=0.05)
    assert off <= OUTER_LINES * tol + 1e-9
    assert len(big_inner) < len(big_outer)  # an inner wall drops every other corner
    assert np.array_equal(small_outer, small_inner)  # a short loop: the whole tolerance


def test_sparse_infill_gets_its_own_tolerance() -> None:
    plan = _plan(**{"gcode.arcs": "off"})
    paths, mv = _moves(plan, 5)
    fill = [k for k, p in enumerate(paths) if p.kind == "FILL"]
    assert fill
    worst = max(
        shapely.hausdorff_distance(shapely.linestrings(paths[k].coords),
                                   shapely.linestrings(mv.pts[mv.starts[k] : mv.ends[k]]),
                                   densify=0.05)
        for k in fill
    )
    assert plan.settings.resolution < worst <= plan.settings.infill_resolution + 1e-9


def test_zero_resolution_keeps_every_point() -> None:
    plan = _plan(**{"gcode.arcs": "off", "resolution": 0.0, "infill.resolution": 0.0})
    paths, mv = _moves(plan, 5)
    pts, _, _ = _pack([p.coords for p in paths])
    assert np.array_equal(mv.pts, pts)


def _arcs_of(lines: list[str]):
    """Each G2/G3 of G-code lines: start, end, centre, ccw, E, feature type."""
    pos = None
    kind = ""
    for line in lines:
        if line.startswith(";TYPE:"):
            kind = line[6:]
        arc = _ARC.match(line)
        if arc:
            g, x, y, i, j, e = arc.groups()
            end = (float(x), float(y))
            yield pos, end, (pos[0] + float(i), pos[1] + float(j)), g == "3", float(e), kind
        move = _MOVE.match(line)
        if move:
            pos = (float(move.group(1)), float(move.group(2)))


def _sweep(start, end, centre, ccw) -> float:
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
    sweep = (a1 - a0) % (2 * math.pi) if ccw else (a0 - a1) % (2 * math.pi)
    return sweep or 2 * math.pi


def test_arcs_lie_on_the_contour_they_replace_and_extrude_by_length() -> None:
    plan = _plan(**{"gcode.arcs": "on"})
    i = 5
    lines = plan.layer_gcode(i)
    contour = shapely.multilinestrings([shapely.linestrings(p.coords)
                                        for p in plan.layer_toolpaths(i)])
    e_per_mm = plan.layer_height(i) * plan.settings.line_width / plan.settings.filament_area
    arcs = list(_arcs_of(lines))
    assert len(arcs) > 10
    assert {a[-1] for a in arcs} >= {"WALL-OUTER", "FILL"}
    for start, end, centre, ccw, e, kind in arcs:
        tol = plan.settings.infill_resolution if kind == "FILL" else plan.settings.resolution
        if kind == "WALL-OUTER":  # the surface's arcs keep closer to the level set
            tol *= OUTER_ARC
        r = math.dist(start, centre)
        sweep = _sweep(start, end, centre, ccw)
        t = np.linspace(0.0, 1.0, 50)
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        ang = a0 + (1 if ccw else -1) * sweep * t
        x, y = centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang)
        far = shapely.distance(contour, shapely.points(x, y)).max()
        assert far <= tol + 0.002  # plus the rounding of X, Y, I and J to 0.001 mm
        assert e == pytest.approx(r * sweep * e_per_mm, rel=2e-3, abs=1e-5)


def test_arcs_cut_lines_and_bytes() -> None:
    without = _plan(**{"gcode.arcs": "off"})
    with_arcs = without.with_settings(SliceSettings.from_mapping({"gcode.arcs": "on"},
                                                                 base=without.settings))
    moves = [sum(1 for line in p.layer_gcode(5) if line.startswith("G")) for p in
             (without, with_arcs)]
    assert moves[1] < 0.7 * moves[0]


def test_arc_output_is_the_same_alone_and_in_sequence() -> None:
    first = _plan(**{"gcode.arcs": "on"})
    run = [first.layer_gcode(i) for i in range(first.layer_count)]
    again = _plan(**{"gcode.arcs": "on"})
    for i in reversed(range(again.layer_count)):
        assert again.layer_gcode(i) == run[i]


def _skin_lines(blocks: list[list[str]]) -> int:
    """Commands under ``;TYPE:SKIN`` in the layers' G-code."""
    count, kind = 0, ""
    for block in blocks:
        for line in block:
            if line.startswith(";TYPE:"):
                kind = line[6:]
            elif kind == "SKIN" and line.startswith(("G1 ", "G2 ", "G3 ")):
                count += 1
    return count


def test_a_cones_skin_bands_alone_and_in_sequence_in_fewer_lines() -> None:
    # a 45-degree cone's shell above its bottom layers is narrow bands: filled along their
    # length for a wire, hatched across without one
    mesh = trimesh.creation.cone(radius=6.0, height=5.0, sections=64)
    settings = SliceSettings.from_mapping({"gcode.arcs": "on"})
    layers = range(4, 12)
    first = SlicePlan.from_mesh(mesh.vertices, mesh.faces, settings)
    run = {i: first.layer_gcode(i) for i in layers}
    again = SlicePlan.from_mesh(mesh.vertices, mesh.faces, settings)
    for i in reversed(layers[::3]):
        assert again.layer_gcode(i) == run[i]
    hatched = first.with_settings(SliceSettings.from_mapping({"gcode.arcs": "off"}))
    across = _skin_lines([hatched.layer_gcode(i) for i in layers])
    assert 0 < _skin_lines(list(run.values())) < 0.6 * across


def test_the_wire_budget_coarsens_only_fast_runs() -> None:
    base = {"gcode.arcs": "off", "print_speed": 150.0, "wall_speed": 150.0}
    free = _plan(**base)
    coarse = {"gcode.coarse_resolution": 0.2}
    slow = free.with_settings(SliceSettings.from_mapping({"gcode.baud": 9600, **coarse},
                                                         base=free.settings))
    paths, plain = _moves(free, 5)
    _, tight = _moves(slow, 5)
    assert line_rate(slow.settings) == pytest.approx(0.8 * 960 / 40)
    assert len(tight.pts) < len(plain.pts)
    limit_walls = slow.settings.gcode_coarse_resolution
    loose = max(limit_walls, slow.settings.infill_resolution)  # sparse infill's own
    for k, path in enumerate(paths):
        exact = shapely.linestrings(path.coords)
        simple = shapely.linestrings(tight.pts[tight.starts[k] : tight.ends[k]])
        limit = loose if path.kind == "FILL" else limit_walls
        assert shapely.hausdorff_distance(exact, simple, densify=0.05) <= limit + 1e-9
        if path.kind == "WALL-OUTER":  # the surface is never coarsened for the wire
            kept = plain.pts[plain.starts[k] : plain.ends[k]]
            assert np.array_equal(tight.pts[tight.starts[k] : tight.ends[k]], kept)
    coarsened = [k for k, p in enumerate(paths)
                 if tight.ends[k] - tight.starts[k] < plain.ends[k] - plain.starts[k]]
    assert coarsened
    assert all(paths[k].kind != "WALL-OUTER" for k in coarsened)
    # a wire fast enough for every run changes nothing
    fast = free.with_settings(SliceSettings.from_mapping({"gcode.baud": 10_000_000, **coarse},
                                                         base=free.settings))
    assert np.array_equal(_moves(fast, 5)[1].pts, plain.pts)


def test_auto_follows_the_firmware_capabilities() -> None:
    auto = SliceSettings()
    assert auto.gcode_arcs == "auto"
    assert for_printer(auto, {"ARCS", "EEPROM"}).gcode_arcs == "on"
    assert for_printer(auto, {"EEPROM"}).gcode_arcs == "off"
    off = SliceSettings.from_mapping({"gcode.arcs": "off"})
    assert for_printer(off, {"ARCS"}).gcode_arcs == "off"
    assert for_printer(auto, set(), 115200).gcode_baud == 115200
    with pytest.raises(SettingsError, match=r"gcode\.arcs"):
        SliceSettings.from_mapping({"gcode.arcs": "yes"})


def test_a_short_fast_run_fits_in_the_planner_and_a_long_one_is_coarsened() -> None:
    # moves of about 0.3 mm at 100 mm/s (3 ms) on a wire of 6 ms a line: each move takes
    # 3 ms more of the wire than it prints, so 16 planner blocks last 32 moves
    settings = SliceSettings.from_mapping({"gcode.arcs": "off", "gcode.baud": 83_333,
                                           "gcode.coarse_resolution": 0.2})
    assert 1.0 / line_rate(settings) == pytest.approx(0.006, rel=1e-3)

    def zigzag(moves: int) -> np.ndarray:
        x = 0.3 * np.arange(moves + 1)
        return np.column_stack([x, 0.1 * (np.arange(moves + 1) % 2)])  # kept at 0.025 mm

    for moves, coarsened in ((20, False), (28, False), (120, True)):
        pts = zigzag(moves)
        mv = budget_moves(pts, np.array([0]), np.array([len(pts)]), np.array([100.0]),
                          settings)
        assert (len(mv.pts) < len(pts)) is coarsened, moves
        outer = budget_moves(pts, np.array([0]), np.array([len(pts)]), np.array([100.0]),
                             settings, exact=np.array([True]))
        assert len(outer.pts) == len(pts)  # an outer wall keeps every point


def _arc_points(start: np.ndarray, mv, j: int, count: int = 200) -> np.ndarray:
    """Points along the arc move into ``mv.pts[j]`` from ``start``: (count, 2) mm."""
    centre = mv.centre[j]
    r = math.dist(start, centre)
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    ang = a0 + (1 if mv.ccw[j] else -1) * (mv.length[j] / r) * np.linspace(0.0, 1.0, count)
    return np.column_stack([centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang)])


def _arcs_within(pts: np.ndarray, mv, tol: float) -> int:
    """Check every arc of ``mv`` against the polyline ``pts`` it replaced, both ways (the
    arc's points near the polyline, the polyline's near the circle); the arcs counted."""
    index = {tuple(p): i for i, p in enumerate(pts)}
    for j in np.flatnonzero(mv.arc):
        a, b = index[tuple(mv.pts[j - 1])], index[tuple(mv.pts[j])]
        line = shapely.linestrings(pts[a : b + 1])
        assert shapely.distance(line, shapely.points(_arc_points(mv.pts[j - 1], mv, j))).max() \
            <= tol
        stretch = shapely.segmentize(line, 0.01)
        rel = shapely.get_coordinates(stretch) - mv.centre[j]
        r = math.dist(mv.pts[j - 1], mv.centre[j])
        assert np.abs(np.hypot(rel[:, 0], rel[:, 1]) - r).max() <= tol
    return int(mv.arc.sum())


def test_the_wave_fields_curves_take_one_arc_a_half_wave() -> None:
    # the wave field's half-waves are circular arcs: each becomes one G2/G3, and the
    # arcs lie on the field's level sets
    settings = SliceSettings.from_mapping({"infill.field": "wave", "gcode.arcs": "on"})
    domain = shapely.box(0.0, 0.0, 40.0, 30.0)
    ctx = LayerContext(0, 0.2, domain, domain.bounds, settings)
    field = get_field(settings)
    paths = shapely.get_parts(field.paths(domain.buffer(-0.6), ctx, 2.0))
    pts, starts, ends = _pack([shapely.get_coordinates(p) for p in paths])
    mv = budget_moves(pts, starts, ends, np.full(len(paths), 60.0), settings,
                      loose=np.ones(len(paths), dtype=bool))
    half_waves = shapely.length(paths).sum() / (5.0 * mean_stretch(1.0))
    moves = len(mv.pts) - len(paths)
    assert moves <= half_waves + 2 * len(paths)  # the clipped ends may take two more
    assert mv.arc.sum() >= 0.8 * half_waves
    _arcs_within(pts, mv, settings.infill_resolution)
    ends_of_arcs = mv.pts[mv.arc]
    on = field.sample(ends_of_arcs[:, 0], ends_of_arcs[:, 1], ctx)
    mids = np.array([_arc_points(mv.pts[j - 1], mv, j, 3)[1] for j in np.flatnonzero(mv.arc)])
    mid_values = field.sample(mids[:, 0], mids[:, 1], ctx)
    # an arc's middle on its end's level set within the tolerance (the field's gradient is
    # at most sqrt(2) at the 45-degree inflections)
    assert np.abs(mid_values - on).max() <= math.sqrt(2.0) * settings.infill_resolution


def test_a_wave_curve_takes_few_moves_each_within_the_tolerance() -> None:
    # the wave field's curve (10 mm wavelength, 45 degree slope) as sampled: lines at the
    # inflections, arcs over the crests, each as long as it can be
    settings = SliceSettings.from_mapping({"gcode.arcs": "on"})
    tol = settings.infill_resolution
    a, b = 10.0 / (2 * math.pi), 2 * math.pi / 10.0
    u = np.arange(0.0, 100.0, 10.0 / 48)
    pts = np.column_stack([u, a * np.sin(b * u)]) @ np.array([[0.8, 0.6], [-0.6, 0.8]])
    mv = budget_moves(pts, np.array([0]), np.array([len(pts)]), np.array([60.0]), settings,
                      loose=np.array([True]))
    moves = len(mv.pts) - 1
    assert moves <= 38  # 3.8 a wavelength (fitting from fixed midpoints took 4.5)
    assert _arcs_within(pts, mv, tol) >= 15
    # as an outer wall, at the walls' tolerance: its arcs keep closer to the vertices
    tol = settings.resolution
    outer = budget_moves(pts, np.array([0]), np.array([len(pts)]), np.array([60.0]), settings,
                         exact=np.array([True]))
    assert _arcs_within(pts, outer, OUTER_ARC * tol) >= 15


def test_an_arc_is_checked_along_its_long_segments_not_only_at_points() -> None:
    # a circle of 5 mm; its first segment (16 degrees long, ending 0.09 mm inside) passes
    # 0.104 mm inside the circle between its midpoint (0.093 mm) and its end
    settings = SliceSettings.from_mapping({"gcode.arcs": "on", "resolution": 0.1})
    ang = np.radians(np.concatenate([[0.0, 16.0], np.arange(19.0, 100.0, 3.0)]))
    radius = np.where(np.arange(len(ang)) == 1, 4.91, 5.0)
    pts = np.column_stack([radius * np.cos(ang), radius * np.sin(ang)])
    mv = budget_moves(pts, np.array([0]), np.array([len(pts)]), np.array([60.0]), settings)
    assert _arcs_within(pts, mv, settings.resolution) >= 1


@pytest.mark.parametrize(("radius", "inner"), [(4.0, 2.0), (2.5, 0.0)])
def test_a_small_rings_outer_wall_keeps_its_region_with_arcs(radius: float, inner: float) -> None:
    # a tube 2 mm thick and a rod of 2.5 mm radius: an arc's deviation counts against a
    # small region, so their outer walls' arcs are held to the island's size (held to
    # OUTER_ARC of the resolution alone, the IoU with the lines was 0.9964 and 0.9939)
    # without arcs ("plain") or with them ("fitted")
    mesh = trimesh.creation.cylinder(radius=radius, height=1.0, sections=256)
    if inner:
        mesh = mesh.difference(trimesh.creation.cylinder(radius=inner, height=3.0, sections=256))
    settings = SliceSettings.from_mapping({"gcode.arcs": "off"})
    plain = SlicePlan.from_mesh(mesh.vertices, mesh.faces, settings)
    fitted = plain.with_settings(SliceSettings.from_mapping({"gcode.arcs": "on"}, base=settings))
    layers = range(2, 4)
    # arcs are fitted (the inner walls' at least)
    assert any(line.startswith(("G2 ", "G3 ")) for i in layers for line in fitted.layer_gcode(i))
    # against the level set itself (the layer's outline w/2 in): the arcs' region keeps
    # to it, at least as closely as the lines' (whose corners lie on it, chords inside)
    w = settings.line_width
    level = {i: shapely.buffer(plain.outline(i), -w / 2, quad_segs=16) for i in layers}
    agree = {}
    for plan in (fitted, plain):
        regions = gcodeparse.outer_wall_regions(gcodeparse.parse_moves(
            plan.start_gcode() + [line for i in layers for line in plan.layer_gcode(i)]))
        assert len(regions) == len(layers)
        agree[plan.settings.gcode_arcs] = min(gcodeparse.layer_iou(
            regions, dict(zip(sorted(regions), level.values(), strict=True))).values())
    # (the arcs follow the mesh's circle, a few um outside the polygon's flats)
    assert agree["on"] >= 0.998
    assert agree["on"] >= agree["off"]
