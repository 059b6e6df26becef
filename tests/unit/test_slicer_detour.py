"""Travels after a cancelled body go around its region; the other bodies still print."""

from __future__ import annotations

import asyncio
import concurrent.futures
import re

import numpy as np
import pytest
import shapely
import trimesh

from hostd.jobs.schedule import LayerSchedule
from hostd.printing.sources import SlicedSource
from slicer.paths.detour import MARGIN, detours
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

MOVE = re.compile(r"^(G[0-3]) (?:F\S+ )?X(\S+) Y(\S+)(?: Z\S+)?(?: I\S+ J\S+)?(?: E(\S+))?")


@pytest.fixture(scope="module")
def row_file(tmp_path_factory):
    """Three bodies in a row, the middle one a cylinder: travels between the outer two
    would cross it."""
    path = tmp_path_factory.mktemp("models") / "row.stl"
    left = trimesh.creation.box((12.0, 30.0, 2.0))
    left.apply_translation((-20.0, 0.0, 1.0))
    middle = trimesh.creation.cylinder(radius=8.0, height=2.0, sections=64)
    middle.apply_translation((0.0, 0.0, 1.0))
    right = trimesh.creation.box((12.0, 30.0, 2.0))
    right.apply_translation((20.0, 0.0, 1.0))
    trimesh.util.concatenate([left, middle, right]).export(path)
    return path


def moves(lines: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Every XY move of a layer: its end (m, 2) mm and whether it extrudes (m,) bool."""
    ends, printing = [], []
    for line in lines:
        found = MOVE.match(line)
        if found:
            ends.append((float(found[2]), float(found[3])))
            printing.append(found[4] is not None and float(found[4]) > 0)
    return np.array(ends), np.array(printing)


def middle_body(plan: SlicePlan, layer: int) -> int:
    polys, owner = plan.layer_bodies(layer)
    centres = shapely.get_coordinates(shapely.centroid(polys))
    return int(owner[np.argmin(np.abs(centres[:, 0]))])


def test_no_travel_crosses_a_cancelled_body_and_the_others_still_print(row_file) -> None:
    row = SlicePlan.from_file(row_file, SliceSettings())
    layer = 5
    body = middle_body(row, layer)
    polys, owner = row.layer_bodies(layer)
    outline = shapely.union_all(polys[owner == body])
    before = row.layer_gcode(layer)
    ends, printing = moves(before)
    travels = shapely.linestrings(np.stack([ends[:-1], ends[1:]], axis=1)[~printing[1:]])
    assert shapely.intersects(travels, outline).any()  # without the cancel, travels cross it

    after = row.layer_gcode(layer, frozenset({body}))
    ends, printing = moves(after)
    travels = shapely.linestrings(np.stack([ends[:-1], ends[1:]], axis=1)[~printing[1:]])
    assert not shapely.intersects(travels, outline).any()
    # they keep the margin (less the rounding of the lines' coordinates)
    assert shapely.distance(travels, outline).min() > MARGIN - 0.01
    # the two other bodies print the same moves as before, and the cancelled one none
    printed = shapely.points(ends[printing])
    old_ends, old_printing = moves(before)
    for other in sorted(set(owner.tolist()) - {body}):
        region = shapely.buffer(polys[owner == other][0], 0.01)
        mine = ends[printing][shapely.covered_by(printed, region)]
        theirs = old_ends[old_printing][shapely.covered_by(
            shapely.points(old_ends[old_printing]), region)]
        assert len(mine) > 10
        assert np.array_equal(mine, theirs)
    assert not shapely.within(printed, shapely.buffer(outline, -0.5)).any()
    # the same layer gives the same bytes, from a fresh plan too
    assert row.layer_gcode(layer, frozenset({body})) == after
    again = SlicePlan.from_file(row_file, SliceSettings())
    assert again.layer_gcode(layer, frozenset({body})) == after


def test_detours_only_where_the_line_meets_the_region() -> None:
    region = shapely.buffer(shapely.Point(0.0, 0.0), 5.0)
    a = np.array([[-10.0, 0.0], [-10.0, 8.0]])
    b = np.array([[10.0, 0.0], [10.0, 8.0]])
    around, clear = detours(a, b, region)
    assert len(clear) == 0
    path = shapely.LineString(np.vstack([a[0], around, b[0]]))
    assert not shapely.intersects(path, region)
    assert shapely.length(path) < 10.0 + np.pi * 6.0  # the shorter way round
    # an end closer to the region than the ring walked (bodies that close)
    near = np.array([[-5.1, 0.5]])
    around = detours(near, b[:1], region)[0]
    path = shapely.LineString(np.vstack([near[0], around, b[0]]))
    assert not shapely.intersects(path, region)


def joined(schedule: LayerSchedule, first: int = 0, resume: bool = False) -> list[list[str]]:
    """Every layer from ``first`` as the daemon takes them, in order (each layer's first
    travel planned from where the one before ended)."""
    async def take() -> list[list[str]]:
        with concurrent.futures.ThreadPoolExecutor(2) as executor:
            source = SlicedSource(schedule, first, 2, executor, resume)
            try:
                return [await source.layer(i) for i in range(first, schedule.layer_count)]
            finally:
                source.close()

    return asyncio.run(take())


def entry_crossings(plan: SlicePlan, layers: list[list[str]], first: int, body: int,
                    cancelled_from: int) -> int:
    """Travels (from the end of one layer into the next included) that cross ``body``'s
    outline on their layer or the one below, from layer ``cancelled_from`` on."""
    crossings = 0
    at = None
    for index, lines in enumerate(layers, start=first):
        ends, printing = moves(lines)
        if at is not None and len(ends) and index >= cancelled_from:
            path = np.vstack([at, ends])
            travels = shapely.linestrings(np.stack([path[:-1], path[1:]], axis=1)[~printing])
            for layer in (index - 1, index):
                polys, owner = plan.layer_bodies(layer)
                outline = shapely.union_all(polys[owner == body])
                crossings += int(shapely.intersects(travels, outline).sum())
        at = ends[-1] if len(ends) else at
    return crossings


def test_the_travel_into_each_layer_goes_around_a_cancelled_body_too(row_file) -> None:
    plan = SlicePlan.from_file(row_file, SliceSettings())
    polys, owner = plan.layer_bodies(3)
    # the cylinder between the boxes: each layer ends in the right box, starts in the left
    body = int(owner[np.argsort(shapely.get_coordinates(shapely.centroid(polys))[:, 0])[1]])
    cancelled_from = 3
    plain = [plan.layer_gcode(i, frozenset({body}) if i >= cancelled_from else frozenset())
             for i in range(plan.layer_count)]
    # sliced on its own, a layer's first travel crosses the body from the last layer's end
    assert entry_crossings(plan, plain, 0, body, cancelled_from) > 0
    schedule = LayerSchedule(plan, plan.settings, cancelled=[(body, cancelled_from)])
    layers = joined(schedule)
    assert entry_crossings(plan, layers, 0, body, cancelled_from) == 0
    # only the first travels changed, and the layer's estimate holds the way round
    for index, (mine, theirs) in enumerate(zip(layers, plain, strict=True)):
        extra = [line for line in mine if line not in theirs]
        assert all(line.startswith("G0 ") for line in extra)
        assert bool(extra) <= (index >= cancelled_from)
        alone = plan.layer_code(index, schedule.excluded_at(index)).time_s
        assert (schedule.estimates[index][0] > alone) == bool(extra)
    assert any(mine != theirs for mine, theirs in zip(layers, plain, strict=True))
    # a resumed job enters its first layer as the uninterrupted one did
    resumed = joined(LayerSchedule(plan, plan.settings, cancelled=[(body, cancelled_from)]),
                     first=5, resume=True)
    assert resumed == layers[5:]
