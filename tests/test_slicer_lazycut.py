"""Outlines cut on demand: same layers in any order and thread, warnings complete when asked."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import shapely

from slicer.lazycut import LazyOutlines
from slicer.mesh import prepare, read_stl
from slicer.plan import SlicePlan, cut_planes, layer_tops
from slicer.settings import SliceSettings
from tests.slicer_helpers import DATA

SETTINGS = SliceSettings()


def test_layers_out_of_order_on_threads_equal_layers_in_order() -> None:
    ordered = SlicePlan.from_file(DATA / "bunny.stl", SETTINGS)
    layers = list(range(0, 48))
    expected = [ordered.layer_gcode(i) for i in layers]
    shuffled = SlicePlan.from_file(DATA / "bunny.stl", SETTINGS)
    order = layers[::-1]
    with ThreadPoolExecutor(4) as pool:
        got = dict(zip(order, pool.map(shuffled.layer_gcode, order), strict=True))
    assert [got[i] for i in layers] == expected


def test_warnings_so_far_grow_and_warnings_cover_every_layer() -> None:
    plan = SlicePlan.from_file(DATA / "bunny.stl", SETTINGS)
    # the bunny's open base is at the bottom: not cut by the whole-model pass
    assert not any("open outlines" in w for w in plan.warnings_so_far)
    plan.layer_gcode(0)
    early = [w for w in plan.warnings_so_far if "open outlines" in w]
    assert early
    full = plan.warnings
    assert any("open outlines" in w for w in full)
    assert plan.warnings_so_far == full
    other = SlicePlan.from_file(DATA / "bunny.stl", SETTINGS)
    other.cut_all()
    assert other.warnings_so_far == full


def test_blocks_of_any_size_give_the_same_outlines() -> None:
    mesh = prepare(*read_stl(DATA / "featuretype_mm.stl"), (220.0, 220.0, 250.0))
    planes = cut_planes(layer_tops(mesh.height, SETTINGS), SETTINGS)
    small = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes, block=3)
    whole = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes, block=len(planes))
    for i in range(0, len(planes), 5):
        assert shapely.to_wkb(small[i]) == shapely.to_wkb(whole[i])
        assert np.array_equal(small.polygons(i)[1], whole.polygons(i)[1])
    assert len(small[2:9]) == 7
