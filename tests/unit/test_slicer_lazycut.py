"""Outlines cut on demand: same layers in any order and thread, warnings complete when asked."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import shapely
from support.slicer_helpers import DATA

from slicer.input.lazycut import LazyOutlines
from slicer.input.mesh import prepare, read_stl
from slicer.plan import SlicePlan, cut_planes, layer_tops
from slicer.settings import SliceSettings

SETTINGS = SliceSettings()


def placed(shape):
    """A trimesh shape placed on the bed, and the planes its layers are cut at."""
    mesh = prepare(np.asarray(shape.vertices), np.asarray(shape.faces), (220, 220, 250))
    return mesh, cut_planes(layer_tops(mesh.height, SETTINGS), SETTINGS)


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


def test_shells_cut_whole_on_threads_give_the_objects_of_one_thread(monkeypatch) -> None:
    """A mesh of shells whose boxes meet (a hollow box with a cube in its cavity, and a
    box overlapping it) is cut whole to number its objects: on several threads the
    objects, outlines and G-code are those of one thread."""
    import trimesh

    import slicer.plan

    outer = trimesh.creation.box(extents=(30, 30, 12))
    cavity = trimesh.creation.box(extents=(20, 20, 8))
    cavity.invert()
    inside = trimesh.creation.box(extents=(6, 6, 4))
    overlapping = trimesh.creation.box(extents=(10, 10, 12))
    overlapping.apply_translation((18, 0, 0))
    mesh = trimesh.util.concatenate([outer, cavity, inside, overlapping])
    plans = []
    for cores in (1, 4):
        monkeypatch.setattr(slicer.plan.os, "cpu_count", lambda cores=cores: cores)
        plans.append(SlicePlan.from_mesh(mesh.vertices, mesh.faces, SETTINGS))
    one, many = plans
    assert one.body_count == many.body_count == 2  # the cube in the cavity, the rest
    assert one.layer_count == many.layer_count
    for i in range(one.layer_count):
        assert shapely.to_wkb(one.outline(i)) == shapely.to_wkb(many.outline(i)), i
        assert np.array_equal(one.layer_bodies(i)[1], many.layer_bodies(i)[1]), i
        assert one.layer_gcode(i) == many.layer_gcode(i), i


def test_light_blocks_are_cut_on_one_thread_heavy_ones_on_several(monkeypatch) -> None:
    """Blocks that took under ``_THREADS_WORTH`` each are cut on the calling thread
    (two would take turns on the interpreter lock); heavier ones on the threads
    asked for, with the same outlines."""
    import threading

    import slicer.input.lazycut

    mesh = prepare(*read_stl(DATA / "featuretype_mm.stl"), (220.0, 220.0, 250.0))
    planes = cut_planes(layer_tops(mesh.height, SETTINGS), SETTINGS)

    def cut_on(worth: float) -> tuple[int, set[str], list[bytes]]:
        monkeypatch.setattr(slicer.input.lazycut, "_THREADS_WORTH", worth)
        outlines = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes, block=4)
        assert outlines.cut_threads(2) == 2  # nothing cut yet: nothing known
        outlines.outline(0)
        threads = outlines.cut_threads(2)
        names: set[str] = set()
        cut = outlines._cut

        def cut_here(b: int) -> object:
            names.add(threading.current_thread().name)
            return cut(b)

        monkeypatch.setattr(outlines, "_cut", cut_here)
        outlines.cut_all(threads=2)
        return threads, names, [shapely.to_wkb(outlines[i]) for i in range(len(planes))]

    light_threads, light_names, light = cut_on(60.0)
    heavy_threads, heavy_names, heavy = cut_on(0.0)
    assert light_threads == 1
    assert light_names == {threading.main_thread().name}
    assert heavy_threads == 2
    assert heavy_names
    assert heavy_names <= {"cut-0", "cut-1"}
    assert light == heavy
    assert len(planes) > 8


def test_blocks_left_are_judged_by_their_faces_against_the_blocks_cut(monkeypatch) -> None:
    """The time of the blocks cut so far is scaled by the faces of the blocks left: a
    sphere's top block (its pole, few faces) at 6 ms says its middle blocks are heavy;
    a box's top block at 6 ms says its other blocks, alike, are light."""
    import trimesh

    import slicer.input.lazycut

    monkeypatch.setattr(slicer.input.lazycut, "_THREADS_WORTH", 0.007)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=15.0)
    box = trimesh.creation.box(extents=(10.0, 10.0, 30.0))
    threads = []
    for shape in (sphere, box):
        mesh, planes = placed(shape)
        outlines = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes, block=16)
        outlines.last_nonempty()  # the top block, as the whole-model pass cuts it
        outlines._cut_seconds = 0.006  # its time, fixed here (measured in a slice)
        threads.append(outlines.cut_threads(2))
    assert threads == [2, 1]


def test_light_layers_are_cut_in_bigger_blocks_with_the_same_outlines(monkeypatch) -> None:
    """A box's layers cross a dozen faces each: cut in blocks of 64 layers (the calls
    per block, not the array work, are most of a light block's time); a fine sphere's
    cross hundreds: blocks of 16. Either way the outlines are those of blocks of 16,
    and a 64-layer block of 6 ms is judged as light as a 16-layer one of 1.5 ms."""
    import trimesh

    import slicer.input.lazycut
    from slicer.input.lazycut import BLOCK, LIGHT_BLOCK

    sphere = trimesh.creation.icosphere(subdivisions=5, radius=15.0)
    box = trimesh.creation.box(extents=(10.0, 10.0, 30.0))
    chosen = []
    for shape in (sphere, box):
        mesh, planes = placed(shape)
        auto = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes)
        fixed = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes, block=BLOCK)
        chosen.append(auto._block)
        for i in range(len(planes)):
            assert shapely.to_wkb(auto[i]) == shapely.to_wkb(fixed[i])
    assert chosen == [BLOCK, LIGHT_BLOCK]
    monkeypatch.setattr(slicer.input.lazycut, "_THREADS_WORTH", 0.007)
    mesh = prepare(np.asarray(box.vertices), np.asarray(box.faces), (220, 220, 250))
    planes = cut_planes(layer_tops(mesh.height * 5, SETTINGS), SETTINGS)
    outlines = LazyOutlines(mesh.vertices * [1, 1, 5], mesh.faces, mesh.face_body, planes)
    assert outlines._block == LIGHT_BLOCK
    assert outlines._block_count() >= 3
    outlines.last_nonempty()
    outlines._cut_seconds = 0.006  # a 64-layer block's time: 1.5 ms per 16 layers
    assert outlines.cut_threads(2) == 1
    outlines._cut_seconds = 0.040  # 10 ms per 16 layers
    assert outlines.cut_threads(2) == 2
