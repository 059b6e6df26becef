"""Layers made a block at a time: the same bytes, filament, time and spans as one by one,
whatever the block's bounds; tasks made by one call; output into a pipe stays a pipe."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest
import trimesh
from support.slicer_helpers import DATA, box_stl, write_mesh

from slicer.output import gcode
from slicer.output.gcodefile import write_gcode
from slicer.pipeline import LayerWindow, in_blocks
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


def _two_bodies(path: Path) -> Path:
    """A box and a cylinder apart on one plate: two bodies, labelled moves, holes."""
    box = trimesh.creation.box(extents=(14.0, 10.0, 6.0))
    box.apply_translation((-12.0, 0.0, 3.0))
    post = trimesh.creation.cylinder(radius=5.0, height=8.0, sections=48)
    post.apply_translation((10.0, 0.0, 4.0))
    return write_mesh(trimesh.util.concatenate([box, post]), path)


def _alone(path: Path, settings: SliceSettings, excluded: frozenset[int] = frozenset()
           ) -> list[gcode.LayerCode]:
    plan = SlicePlan.from_file(path, settings)
    return [plan.layer_code(i, excluded) for i in range(plan.layer_count)]


def _blocks(path: Path, settings: SliceSettings, bounds: list[int],
            excluded: frozenset[int] = frozenset()) -> list[gcode.LayerCode]:
    plan = SlicePlan.from_file(path, settings)
    cuts = [b for b in bounds if b < plan.layer_count] + [plan.layer_count]
    codes: list[gcode.LayerCode] = []
    for lo, hi in zip([0, *cuts[:-1]], cuts, strict=True):
        codes += plan.layer_codes(lo, hi, excluded)
    return codes


def _same(a: list[gcode.LayerCode], b: list[gcode.LayerCode]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.lines == y.lines
        assert (x.filament_mm, x.time_s, x.z_line) == (y.filament_mm, y.time_s, y.z_line)
        assert (x.spans is None) == (y.spans is None)
        if x.spans is not None:
            assert np.array_equal(x.spans, y.spans)


@pytest.mark.parametrize("variant", [
    {},  # one pass over the block
    {"gcode.arcs": "on"},  # arcs: the budget layer by layer (islands' scale)
    {"gcode.baud": 115200},  # the wire's budget looks along each layer's moves
])
def test_blocks_of_layers_give_the_bytes_of_layers_made_alone(tmp_path: Path, variant) -> None:
    model = _two_bodies(tmp_path / "two.stl")
    settings = SliceSettings.from_mapping({"fan_first_layer": 2, **variant})
    alone = _alone(model, settings)
    assert any(code.spans is not None and len(code.spans) for code in alone)
    _same(alone, _blocks(model, settings, [3, 4, 16, 40]))
    _same(alone, _blocks(model, settings, [len(alone)]))  # the whole model at once


def test_blocks_split_by_their_points_and_around_a_cancelled_body_agree(
    tmp_path: Path, monkeypatch
) -> None:
    model = _two_bodies(tmp_path / "two.stl")
    settings = SliceSettings()
    excluded = frozenset({1})
    alone = _alone(model, settings, excluded)
    monkeypatch.setattr(gcode, "BATCH_POINTS", 500)  # many passes within a block
    _same(alone, _blocks(model, settings, [16], excluded))
    curved = _alone(DATA / "bunny.stl", settings)
    _same(curved, _blocks(DATA / "bunny.stl", settings, [1, 9, 25]))


def test_repeated_layers_in_a_block_are_the_layers_sliced(tmp_path: Path) -> None:
    model = box_stl(tmp_path / "box.stl", (20.0, 20.0, 12.0))  # every middle layer alike
    plan = SlicePlan.from_file(model, SliceSettings())
    made = plan.layer_codes(0, plan.layer_count)
    fresh = SlicePlan.from_file(model, SliceSettings())
    fresh._reuse = False
    _same(made, [fresh.layer_code(i) for i in range(fresh.layer_count)])


def test_a_block_engine_makes_each_task_in_one_call() -> None:
    calls: list[tuple[int, int]] = []

    def make(lo: int, hi: int) -> list[str]:
        calls.append((lo, hi))
        return [f"layer {i}" for i in range(lo, hi)]

    window = LayerWindow(in_blocks(make, [(0, 3), (3, 4), (4, 9)]), 10, depth=1)
    assert list(window) == [f"layer {i}" for i in range(10)]
    assert calls == [(0, 3), (3, 4), (4, 9), (9, 10)]  # layer 9 in no task: alone


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")
def test_gcode_written_into_a_named_pipe_leaves_the_pipe(tmp_path: Path) -> None:
    model = box_stl(tmp_path / "box.stl", (10.0, 10.0, 2.0))
    plan = SlicePlan.from_file(model, SliceSettings())
    pipe = tmp_path / "out.gcode"
    os.mkfifo(pipe)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(pipe.read_bytes()))
    reader.start()
    summary = write_gcode(plan, pipe, workers=1)
    reader.join(10)
    assert pipe.is_fifo()  # not replaced by a file renamed onto it
    text = got[0].decode("ascii")
    assert text.count(";LAYER:") == summary.layers == plan.layer_count
    assert not list(tmp_path.glob(".hostd-*"))
