"""Skin regions: what they mean, the same bits whatever block makes them, no slivers."""

from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np
import pytest
import shapely

from slicer.paths import skinfill
from slicer.paths.skins import _OPEN, SkinCache, _domains, skin_regions

DATA = Path(__file__).resolve().parents[1] / "data"

FILL = 0.8  # mm from an outline to its infill domain


def _stack() -> np.ndarray:
    """Outlines of a stepped part with holes coming and going, (40,) object array.

    A 40 mm plate (layers 0-9), a hole through layers 4-13, a 20 mm tower
    on it (layers 10-29) with a hole in layers 18-23, an empty layer 30, and a
    slowly turning square (layers 31-39).
    """
    plate = shapely.box(0, 0, 40, 40)
    tower = shapely.box(10, 10, 30, 30)
    out = []
    for i in range(40):
        if i < 10:
            g = plate
        elif i < 30:
            g = tower
        elif i == 30:
            g = shapely.Polygon()
        else:
            g = shapely.affinity.rotate(shapely.box(5, 5, 25, 25), 2.0 * (i - 31))
        if 4 <= i < 14:
            g = g.difference(shapely.Point(20, 20).buffer(3, quad_segs=8))
        if 18 <= i < 24:
            g = g.difference(shapely.box(14, 14, 18, 26))
        out.append(g)
    return np.array(out, dtype=object)


def _reference(outlines: np.ndarray, top: int, bottom: int) -> list[shapely.Geometry]:
    """Skins by the definition, one layer and one neighbour at a time."""
    fill = _domains(outlines, FILL)
    n = len(fill)
    out = []
    for i in range(n):
        skin = shapely.Polygon()
        for count, step in ((top, 1), (bottom, -1)):
            if count == 0:
                continue
            nbrs = [i + step * k for k in range(1, count + 1)]
            if any(j < 0 or j >= n or fill[j].is_empty for j in nbrs):
                skin = skin.union(fill[i])
                continue
            cover = fill[nbrs[0]]
            for j in nbrs[1:]:
                cover = cover.intersection(fill[j])
            skin = skin.union(fill[i].difference(cover))
        # a part narrower than 2 _OPEN everywhere is no skin
        parts = [p for p in shapely.get_parts(skin) if not p.buffer(-_OPEN).is_empty]
        out.append(shapely.union_all(parts) if parts else shapely.Polygon())
    return out


def _wkb(g: shapely.Geometry | None) -> bytes | None:
    return None if g is None else g.wkb


@pytest.mark.parametrize(("top", "bottom"), [(3, 3), (2, 4), (0, 3), (3, 0), (1, 1)])
def test_skins_mean_the_definition(top: int, bottom: int) -> None:
    outlines = _stack()
    got = skin_regions(outlines, FILL, top, bottom)
    want = _reference(outlines, top, bottom)
    for i, (g, w) in enumerate(zip(got, want, strict=True)):
        g = shapely.Polygon() if g is None else g
        assert shapely.is_valid(g), i
        assert g.symmetric_difference(w).area < 1e-3, i


@pytest.mark.parametrize(("top", "bottom"), [(3, 3), (2, 5), (4, 0)])
def test_same_bits_whatever_block_and_order(top: int, bottom: int) -> None:
    outlines = _stack()
    whole = skin_regions(outlines, FILL, top, bottom)
    order = list(range(len(outlines)))
    random.Random(7).shuffle(order)
    for block in (16, 4):
        cache = SkinCache(outlines, FILL, top, bottom, block=block)
        assert {i: _wkb(cache.get(i)) for i in order} == {i: _wkb(g) for i, g in enumerate(whole)}
    for i in order[:10]:  # each layer alone
        assert _wkb(SkinCache(outlines, FILL, top, bottom).get(i)) == _wkb(whole[i])


def test_cache_forgets_what_no_block_needs() -> None:
    outlines = _stack()
    cache = SkinCache(outlines, FILL, 3, 3, block=8)
    for i in range(len(outlines)):
        cache.get(i)
    assert not cache._fill
    assert not cache._cover


def test_no_slivers_between_nearly_equal_layers() -> None:
    # a column whose layers differ by a tenth of a micron has skin at its ends only
    base = shapely.Point(0, 0).buffer(10, quad_segs=16).difference(shapely.box(-2, -2, 2, 2))
    outlines = np.array(
        [shapely.affinity.translate(base, 1e-4 * (i % 3), -1e-4 * (i % 2)) for i in range(20)],
        dtype=object,
    )
    skins = skin_regions(outlines, FILL, 3, 3)
    assert all(g is not None for g in skins[:3])
    assert all(g is not None for g in skins[-3:])
    assert all(g is None for g in skins[3:-3])


def test_no_skins_without_solid_layers() -> None:
    assert all(g is None for g in skin_regions(_stack(), FILL, 0, 0))


def test_steep_sides_get_no_hair_thin_skin_shallow_ones_a_band() -> None:
    # a pyramid whose sides move 0.1 mm a layer (steep: the 3-layer cover misses a
    # 0.3 mm band, narrower than a line) and then 0.5 mm a layer (a 1.5 mm band)
    steep = [shapely.box(0, 0, 40, 40).buffer(-0.1 * i, join_style="mitre") for i in range(10)]
    shallow = [steep[-1].buffer(-0.5 * i, join_style="mitre") for i in range(1, 10)]
    outlines = np.array(steep + shallow, dtype=object)
    skins = skin_regions(outlines, FILL, 3, 0)
    assert all(g is None for g in skins[3:6])  # covered but for a 0.3 mm band: no skin
    band = skins[12]
    assert band is not None
    domain = _domains(outlines[12:13], FILL)[0]
    # the band under the next three layers' edges: 1.5 mm wide along the domain's edge
    assert band.area == pytest.approx(domain.area - domain.buffer(-1.5).area, rel=0.05)


def test_a_narrow_band_of_skin_is_filled_along_its_length() -> None:
    # a sloped shell's band: between the infill domain's edge (a 10 mm circle) and the
    # cover of the layer above (a 9 mm circle off centre), 0.5-1.5 mm wide; and a wide part
    w = 0.4
    fill = shapely.Point(0, 0).buffer(10.0, quad_segs=32)
    band = fill.difference(shapely.Point(0.5, 0).buffer(9.0, quad_segs=32))
    square = shapely.box(-3, -3, 3, 3)
    skin = np.array([shapely.multipolygons([band]), shapely.multipolygons([square])],
                    dtype=object)
    fills = np.array([fill, shapely.box(-5, -5, 5, 5)], dtype=object)
    narrow, wide = skinfill.split_narrow(skin, w)
    assert narrow[0].equals(band)
    assert wide[0] is None
    assert narrow[1] is None
    assert wide[1].equals(skin[1])
    lines, rest = skinfill.along(narrow, wide, fills, w)
    assert lines[1] == []
    assert rest[1].equals(skin[1])
    # a few long lines around the band (hatched across it was ~150 chords)
    assert 1 <= len(lines[0]) <= 6
    assert min(len(c) for c in lines[0]) > 10
    paths = np.array([shapely.linestrings(c) for c in lines[0]], dtype=object)
    # each on a level set of the distance to the domain's edge, half a line plus whole ones in
    depth = shapely.distance(shapely.boundary(fill), shapely.points(np.concatenate(lines[0])))
    k = (depth - 0.5 * w) / w
    assert np.allclose(k, np.round(k), atol=0.01)
    # the band is solid: the lines, and the hatch of what they leave, cover it, but for
    # strips thinner than half a line along the cover's edge
    covered = shapely.union_all(shapely.buffer(paths, 0.5 * w))
    if rest[0] is not None:
        covered = covered.union(rest[0])
    assert shapely.intersection(covered, band).area >= 0.93 * band.area
    assert shapely.intersection(covered, band).area <= band.area
    # and no line is laid over another
    beads = shapely.buffer(paths, 0.45 * w)
    assert shapely.union_all(beads).area >= 0.97 * shapely.area(beads).sum()


def test_a_band_geos_cannot_overlay_exactly_is_filled_on_the_precision_grid() -> None:
    # a real layer (the bracket's, arcs on) where GEOS's exact overlay of what the lines
    # leave with the band raised a topology error and the whole slice failed
    case = json.loads((DATA / "skinfill_overlay_case.json").read_text())

    def shapes(key: str) -> np.ndarray:
        return np.array([None if s is None else shapely.from_wkt(s) for s in case[key]],
                        dtype=object)

    narrow, wide, fill = shapes("narrow"), shapes("wide"), shapes("fill")
    w = case["w"]
    lines, rest = skinfill.along(narrow, wide, fill, w)
    assert all(len(lines[i]) >= 1 for i, g in enumerate(narrow) if g is not None)
    # what the lines leave and the skin left to the hatch stay inside the island's skin
    for i, g in enumerate(narrow):
        if g is None or rest[i] is None:
            continue
        skin = g if wide[i] is None else g.union(wide[i])
        assert rest[i].difference(skin.buffer(1e-4)).area < 1e-6


def _island_domains(outlines: np.ndarray) -> np.ndarray:
    # the plan's domains: each island's own, walls of 0.4 mm, FILL mm in
    from slicer.paths.islands import island_domains

    return island_domains(outlines, 0.4, 2, FILL, "outer_first")


def test_skins_from_the_islands_domains_are_the_skins_of_the_buffered_outlines() -> None:
    from slicer.paths import islands

    outlines = _stack()
    islands.forget()
    plain = skin_regions(outlines, FILL, 3, 3)
    ours = SkinCache(outlines, FILL, 3, 3, inward=_island_domains).solve(0, len(outlines))
    for i, (a, b) in enumerate(zip(plain, ours, strict=True)):
        a = shapely.Polygon() if a is None else a
        b = shapely.Polygon() if b is None else b
        assert shapely.is_valid(b), i
        assert a.symmetric_difference(b).area < 1e-6, i
    # and the islands' walls were made on the way: the layers' toolpaths find them kept
    assert islands._kept()


def test_an_islands_domain_is_its_buffer_and_empty_inside_an_empty_wall() -> None:
    from slicer.paths.islands import island_domains, island_geometry

    wide = shapely.box(0, 0, 10, 4).difference(shapely.box(3, 1, 4, 3))
    strut = shapely.box(20, 0, 20.9, 8)  # its second wall level (0.6 mm in) is empty
    layer = shapely.MultiPolygon([wide, strut])
    got = island_domains(np.array([layer, shapely.MultiPolygon(), strut], dtype=object),
                         0.4, 2, FILL, "outer_first")
    want = shapely.buffer(wide, -FILL, quad_segs=6)
    assert got[0].geom_type == want.geom_type == "MultiPolygon"  # the hole splits it
    assert got[0].symmetric_difference(want).area < 1e-9
    assert got[1].is_empty
    assert got[2].is_empty
    _, fill, rings = island_geometry(np.array([strut], dtype=object), 0.4, 2, FILL,
                                     "outer_first")
    assert fill[0].is_empty  # no domain
    assert len(rings[0])  # but walls


def test_a_large_outline_is_buffered_whole_to_the_same_domain(monkeypatch) -> None:
    from slicer.paths import islands

    outlines = _stack()
    own = islands.island_domains(outlines, 0.4, 2, FILL, "outer_first")
    islands.forget()
    monkeypatch.setattr(islands, "DOMAIN_POINTS", 0)  # every outline counts as large
    whole = islands.island_domains(outlines, 0.4, 2, FILL, "outer_first")
    assert not islands._kept()  # no island's walls were made for it
    for i, (a, b) in enumerate(zip(own, whole, strict=True)):
        assert a.symmetric_difference(b).area < 1e-9, i
