"""Outline blocks cut in forked processes: the outlines, bodies and repairs of one process,
a failed child's share cut here instead, the blocks sent back bit for bit."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import shapely
from support.slicer_helpers import DATA

from slicer.input import forkcut
from slicer.input.lazycut import LazyOutlines
from slicer.input.mesh import prepare, read_stl
from slicer.plan import cut_planes, layer_tops
from slicer.settings import SliceSettings

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")

SETTINGS = SliceSettings()


def outlines_of(name: str) -> LazyOutlines:
    mesh = prepare(*read_stl(DATA / name), (220.0, 220.0, 250.0))
    planes = cut_planes(layer_tops(mesh.height, SETTINGS), SETTINGS)
    return LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes)


def same_outlines(a: LazyOutlines, b: LazyOutlines) -> None:
    assert len(a) == len(b)
    for i in range(len(a)):
        assert shapely.to_wkb(a[i]) == shapely.to_wkb(b[i]), i
        polys_a, bodies_a = a.polygons(i)
        polys_b, bodies_b = b.polygons(i)
        assert list(shapely.to_wkb(polys_a)) == list(shapely.to_wkb(polys_b)), i
        assert np.array_equal(bodies_a, bodies_b), i
        assert bodies_a.dtype == bodies_b.dtype, i


def test_blocks_cut_in_a_child_and_here_are_those_of_one_process() -> None:
    """The bunny (open underside: gaps bridged and chains dropped, reported) cut by a
    child from the top down and here from the bottom up: every layer's outline,
    polygons, bodies and the repairs reported are those of one thread; the child
    cut some blocks, reserved ones were left here."""
    one = outlines_of("bunny.stl")
    one.cut_all()
    two = outlines_of("bunny.stl")
    kept: list[int] = []
    keep = two._keep
    two._keep = lambda b, polygons: (kept.append(b), keep(b, polygons))[1]
    away = two.cut_away(reserved_layers=40)  # the first 3 blocks of 16
    assert away is not None
    two.outline(0)  # the first block cut here meanwhile
    top = two._block_count() - 1
    deadline = time.monotonic() + 30.0
    while not away._taken[top] and time.monotonic() < deadline:
        time.sleep(0.001)  # the child begins at the top
    away.meet()
    assert set(two._blocks) == set(range(two._block_count()))
    same_outlines(one, two)
    assert one.report() == two.report()
    assert two.report()[0].closed > 0
    # block 0 was cut here before meeting; 1 and 2 (reserved) here in meet(); the
    # child's from the top down: the top block is among them
    assert kept[:2] == [1, 2]
    assert two._block_count() - 1 in kept[2:]


def test_a_child_that_fails_leaves_its_blocks_to_be_cut_here(monkeypatch) -> None:
    """A child whose cut raises (here: any block cut outside this process) exits 1
    having sent nothing: its blocks are cut here, with the same outlines."""
    parent = os.getpid()
    one = outlines_of("featuretype_mm.stl")
    one.cut_all()
    two = outlines_of("featuretype_mm.stl")
    real = LazyOutlines._cut_polygons
    cut_here: list[int] = []

    def only_here(self: LazyOutlines, b: int):
        if os.getpid() != parent:
            raise MemoryError("no memory in the child")
        cut_here.append(b)
        return real(self, b)

    monkeypatch.setattr(LazyOutlines, "_cut_polygons", only_here)
    away = two.cut_away()
    assert away is not None
    away.meet()
    assert sorted(cut_here) == list(range(two._block_count()))  # every block, here
    same_outlines(one, two)


def test_closing_a_child_not_met_ends_it_and_keeps_nothing() -> None:
    """:meth:`close` before :meth:`meet` kills and reaps the child; nothing of it is
    kept, and the outlines are still cut here on demand."""
    outlines = outlines_of("featuretype_mm.stl")
    away = outlines.cut_away()
    assert away is not None
    away.close()
    with pytest.raises(ChildProcessError):
        os.waitpid(away.pid, os.WNOHANG)
    assert not outlines._blocks
    fresh = outlines_of("featuretype_mm.stl")
    top = len(outlines) - 1
    assert shapely.to_wkb(outlines[top]) == shapely.to_wkb(fresh[top])
    assert len(outlines[top].geoms) > 0


def test_packed_blocks_come_back_bit_for_bit_with_empty_layers() -> None:
    """Blocks with empty layers (an ascending plate of gaps) and repaired layers are
    unpacked to polygons of the same WKB, bodies of the same values and type, and
    the same reports."""
    outlines = outlines_of("candle_stand.stl")
    blocks = {b: outlines._cut_polygons(b) for b in (0, outlines._block_count() - 1)}
    empty = (np.empty(0, dtype=object),), (np.empty(0, dtype=np.int64),), blocks[0][2]
    blocks[99] = empty
    back = forkcut.unpack(forkcut.pack(blocks))
    assert list(back) == list(blocks)
    for b, (polys, bodies, report) in blocks.items():
        got_polys, got_bodies, got_report = back[b]
        assert len(got_polys) == len(polys)
        for p, q in zip(polys, got_polys, strict=True):
            assert list(shapely.to_wkb(p)) == list(shapely.to_wkb(q))
        for p, q in zip(bodies, got_bodies, strict=True):
            assert np.array_equal(p, q)
            assert p.dtype == q.dtype
        assert got_report == report


def test_an_error_here_while_meeting_ends_the_child_and_is_raised(monkeypatch) -> None:
    """A cut that fails in this process while meeting the child (a bad layer) is
    raised at once, the child killed and reaped rather than left cutting."""
    parent = os.getpid()
    outlines = outlines_of("featuretype_mm.stl")
    real = LazyOutlines._cut_polygons

    def fails_here(self: LazyOutlines, b: int):
        if os.getpid() == parent:
            raise ValueError(f"block {b} cannot be cut")
        return real(self, b)

    monkeypatch.setattr(LazyOutlines, "_cut_polygons", fails_here)
    away = outlines.cut_away()
    assert away is not None
    with pytest.raises(ValueError, match="block 0 cannot be cut"):
        away.meet()
    with pytest.raises(ChildProcessError):
        os.waitpid(away.pid, os.WNOHANG)
    away.close()  # nothing left to end
