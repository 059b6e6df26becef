"""Outline blocks cut in forked processes: the outlines, bodies and repairs of one process,
a failed child's share cut here instead, the blocks sent back bit for bit."""

from __future__ import annotations

import os

import numpy as np
import pytest
import shapely

from slicer import forkcut
from slicer.lazycut import LazyOutlines
from slicer.mesh import prepare, read_stl
from slicer.plan import cut_planes, layer_tops
from slicer.settings import SliceSettings
from tests.slicer_helpers import DATA

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


def test_blocks_cut_in_two_processes_are_those_of_one() -> None:
    """The bunny (open underside: gaps bridged and chains dropped, reported) cut
    here and in a child: every layer's outline, polygons, bodies and the repairs
    reported are those of one thread; nothing was left uncut."""
    one = outlines_of("bunny.stl")
    one.cut_all()
    two = outlines_of("bunny.stl")
    two.cut_in_processes(2)
    assert two._block_count() >= 2
    assert set(two._blocks) == set(range(two._block_count()))
    same_outlines(one, two)
    assert one.report() == two.report()
    todo = list(range(two._block_count()))
    child = forkcut.balanced_shares(todo, np.diff(two._offsets)[todo], 2)[1]
    assert any(two._blocks[b].report.closed for b in child)  # repairs came back from it


def test_a_child_that_fails_leaves_its_share_to_be_cut_here(monkeypatch) -> None:
    """A child whose cut raises (here: any block cut outside this process) sends
    nothing and exits 1: its blocks are cut here, with the same outlines."""
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
    two.cut_in_processes(2)
    assert sorted(cut_here) == list(range(two._block_count()))  # both shares, here
    same_outlines(one, two)


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


def test_shares_balance_the_blocks_weights() -> None:
    """Heaviest first to the lightest share: weights 9, 1, 1, 1, 8, 2 in two shares
    of 11 each; every block in exactly one share, each share ascending."""
    shares = forkcut.balanced_shares([10, 11, 12, 13, 14, 15], np.array([9, 1, 1, 1, 8, 2]), 2)
    weight = dict(zip([10, 11, 12, 13, 14, 15], [9, 1, 1, 1, 8, 2], strict=True))
    assert sorted(b for share in shares for b in share) == [10, 11, 12, 13, 14, 15]
    assert [sum(weight[b] for b in share) for share in shares] == [11, 11]
    assert all(share == sorted(share) for share in shares)

