"""G-code other hosts understand: thumbnails, object labels and M73, parsed back from the files."""

from __future__ import annotations

import base64
import io
import re
import subprocess
from pathlib import Path

import pytest
import shapely
import trimesh
from PIL import Image
from support.daemon_helpers import small_box
from support.daemon_process import sim_config
from support.gcode_lines import commands_of
from support.paths import HOSTD, ROOT

from slicer.settings import SettingsError, SliceSettings

_WORD = re.compile(r"([XYE])(-?[\d.]+)")


def two_bodies(path: Path) -> Path:
    """A 20 x 20 x 8 mm block and a 10 x 30 x 6 mm bar beside it, one STL."""
    cube = trimesh.creation.box((20.0, 20.0, 8.0))
    cube.apply_translation((-15.0, 0.0, 4.0))
    bar = trimesh.creation.box((10.0, 30.0, 6.0))
    bar.apply_translation((15.0, 0.0, 3.0))
    trimesh.util.concatenate([cube, bar]).export(path)
    return path


def thumbnails(lines: list[str]) -> dict[tuple[int, int], Image.Image]:
    """Every ``; thumbnail begin WxH LEN`` block decoded, checked against its length."""
    found = {}
    for k, line in enumerate(lines):
        if line.startswith("; thumbnail begin "):
            size, length = line.split()[3:5]
            end = lines.index("; thumbnail end", k)
            text = "".join(item[2:] for item in lines[k + 1:end])
            assert len(text) == int(length)
            image = Image.open(io.BytesIO(base64.b64decode(text)))
            image.load()
            assert image.format == "PNG"
            width, height = map(int, size.split("x"))
            found[(width, height)] = image
    return found


def objects(lines: list[str]) -> dict[str, shapely.Polygon]:
    """The EXCLUDE_OBJECT_DEFINE outlines by name (and M486 T counts them)."""
    defined = {}
    for line in lines:
        if line.startswith("EXCLUDE_OBJECT_DEFINE"):
            words = dict(word.split("=", 1) for word in line.split()[1:])
            points = [tuple(map(float, p.split(","))) for p in
                      words["POLYGON"].strip("[]").split("],[")]
            defined[words["NAME"]] = shapely.Polygon(points)
            centre = tuple(map(float, words["CENTER"].split(",")))
            assert defined[words["NAME"]].contains(shapely.Point(centre))
    assert f"M486 T{len(defined)}" in lines
    return defined


def check_labelled_moves(lines: list[str], defined: dict[str, shapely.Polygon]) -> int:
    """Every extruding move inside the layers lies between its object's start and end, and
    within that object's outline; returns how many were checked."""
    inside: str | None = None
    marlin: int | None = None
    x = y = None
    checked = 0
    in_layers = False
    names = list(defined)
    grown = {name: shapely.buffer(polygon, 0.5) for name, polygon in defined.items()}
    for polygon in grown.values():
        shapely.prepare(polygon)
    for line in lines:
        if line.startswith(";LAYER:"):
            in_layers = True
        elif line.startswith(";END"):
            in_layers = False
        if line.startswith("EXCLUDE_OBJECT_START"):
            assert inside is None
            inside = line.split("NAME=")[1]
            assert marlin == names.index(inside)
        elif line.startswith("EXCLUDE_OBJECT_END"):
            assert line.split("NAME=")[1] == inside
            inside = None
        elif line.startswith("M486 S"):
            marlin = int(line[6:])
            assert inside is None  # S<n> just before the start, S-1 just after the end
        elif line.startswith(("G0 ", "G1 ")):
            words = dict(_WORD.findall(line.split(";")[0]))
            nx, ny = float(words.get("X", x or 0)), float(words.get("Y", y or 0))
            if in_layers and float(words.get("E", 0)) > 0 and (nx, ny) != (x, y):
                assert inside is not None, line
                assert shapely.contains_xy(grown[inside], nx, ny), line
                checked += 1
            x, y = nx, ny
    assert inside is None
    return checked


def check_progress(lines: list[str]) -> None:
    """M73 after every ``;LAYER:`` line: percent rising to 100, minutes falling to 0."""
    marks = [(int(m[1]), int(m[2])) for m in
             (re.fullmatch(r"M73 P(\d+) R(\d+)", line) for line in lines) if m]
    layers = sum(line.startswith(";LAYER:") for line in lines)
    assert len(marks) == layers + 1
    percents, minutes = zip(*marks, strict=True)
    assert list(percents) == sorted(percents)
    assert percents[0] == 0
    assert percents[-1] == 100
    assert list(minutes) == sorted(minutes, reverse=True)
    assert minutes[-1] == 0
    for k, line in enumerate(lines):
        if line.startswith(";LAYER:"):
            assert lines[k + 1].startswith("M73 P")


def test_hostd_slice_writes_thumbnails_labels_and_progress(tmp_path: Path) -> None:
    model = two_bodies(tmp_path / "pair.stl")
    out = tmp_path / "pair.gcode"
    result = subprocess.run(
        [*HOSTD, "slice", str(model), "-o", str(out), "--quiet",
         "--set", 'gcode.thumbnails="16x16,300x200"'],
        capture_output=True, text=True, timeout=120, env={"PYTHONPATH": str(ROOT)},
    )
    assert result.returncode == 0, result.stderr
    lines = out.read_text().splitlines()
    pictures = thumbnails(lines)
    assert {size: image.size for size, image in pictures.items()} == {
        (16, 16): (16, 16), (300, 200): (300, 200)}
    assert pictures[(300, 200)].getchannel("A").getextrema() == (0, 255)  # a part on clear
    defined = objects(lines)
    assert set(defined) == {"body_0", "body_1"}
    assert check_labelled_moves(lines, defined) > 500
    check_progress(lines)


def test_the_daemon_done_file_carries_them_too_equals_hostd_slice_s_and_one_body_has_none(
    daemon, tmp_path: Path
) -> None:
    # the simulated printer accelerates at 1500 mm/s²: the daemon learns it (M503) at
    # connect, as no [slicing] acceleration is configured, and its estimates use it
    hostd = daemon(sim_config(extra="acceleration = 1500\n"))
    model = two_bodies(tmp_path / "pair.stl")
    hostd.drop(model, "pair.stl")
    hostd.drop(small_box(tmp_path / "box.stl"), "cube.stl")
    done = hostd.jobs / "done"
    hostd.wait_for(lambda: (done / "cube.summary.txt").exists(), 120, "both printed")
    lines = (done / "pair.gcode").read_text().splitlines()
    assert set(thumbnails(lines)) == {(32, 32), (220, 124)}  # the default sizes
    defined = objects(lines)
    assert len(defined) == 2
    assert check_labelled_moves(lines, defined) > 500
    check_progress(lines)
    cube = (done / "cube.gcode").read_text().splitlines()
    assert not any(line.startswith(("M486", "EXCLUDE_OBJECT")) for line in cube)
    check_progress(cube)
    assert "acceleration 1500 mm/s² learned from the printer (M503)" in hostd.log()
    # hostd slice at that acceleration writes the same file: the same moves, totals
    # (;TIME:, filament), labels, M73 (at its default 1000 mm/s² the times would differ)
    sliced = tmp_path / "sliced.gcode"
    result = subprocess.run([*HOSTD, "slice", str(model), "-o", str(sliced), "--quiet",
                             "--set", "acceleration=1500"], capture_output=True, text=True,
                            timeout=120, env={"PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr
    assert sliced.read_text().splitlines() == lines
    assert any(line.startswith(";TIME:") for line in lines[:5])
    # what was streamed is the file without the lines written for other hosts
    assert len(commands_of(done / "pair.gcode")) < len([c for c in lines if c[:1] not in ";"])
    assert hostd.stop() == 0


def test_thumbnail_sizes_are_checked() -> None:
    assert SliceSettings.from_mapping({"gcode.thumbnails": ""}).gcode_thumbnails == ""
    for bad in ("32", "0x10", "10x2000", "32x32;64x64"):
        with pytest.raises(SettingsError, match=r"gcode\.thumbnails"):
            SliceSettings.from_mapping({"gcode.thumbnails": bad})


def test_moves_go_to_the_body_whose_polygon_holds_them(monkeypatch) -> None:
    """Each point inside exactly one polygon gets that polygon's body, the others the
    nearest polygon's, whether the box tests run in one block or in many."""
    import numpy as np
    import shapely

    from slicer.output import labels

    rng = np.random.default_rng(5)
    centres = rng.uniform(0, 100, (30, 2))
    polys = shapely.buffer(shapely.points(centres), rng.uniform(2, 9, 30), quad_segs=3)
    polys = polys[np.argsort(shapely.area(polys))]
    keep = [0]  # an outline's polygons do not overlap
    for k in range(1, len(polys)):
        if not shapely.intersects(polys[k], polys[keep]).any():
            keep.append(k)
    polys = polys[keep]
    bodies = rng.integers(0, 4, len(polys))
    outline = shapely.multipolygons(polys)
    points = rng.uniform(-5, 105, (1200, 2))
    inside = shapely.contains_xy(polys[:, None], points[None, :, 0], points[None, :, 1])
    once = inside.sum(axis=0) == 1
    expected = bodies[inside.argmax(axis=0)]
    assert 50 < once.sum() < len(points)
    whole = labels.nearest_body(shapely.get_parts(outline), bodies, points, outline)
    monkeypatch.setattr(labels, "_PAIRS", 2000)  # one polygon at a time
    blocks = labels.nearest_body(shapely.get_parts(outline), bodies, points, outline)
    assert (whole[once] == expected[once]).all()
    assert (whole == blocks).all()
    # the others: a polygon of the body given is among the nearest
    distance = shapely.distance(polys[:, None], shapely.points(points[~once])[None, :])
    mine = np.where(bodies[:, None] == whole[~once][None, :], distance, np.inf)
    assert (mine.min(axis=0) == distance.min(axis=0)).all()


def test_objects_defined_by_the_hull_of_their_sampled_outlines() -> None:
    """A body's footprint is the convex hull of its outlines on the sampled layers, the
    same polygon as the hull of their union; a body absent from every sampled layer
    (between two of them) is not defined, and the others still are."""
    import numpy as np
    import shapely

    from slicer.output.labels import ObjectLabels

    class Layers:  # the three things the definitions read of a plan
        layer_count = 60
        body_count = 4

        def layer_bodies(self, i: int) -> tuple[np.ndarray, np.ndarray]:
            polys = [shapely.box(0, 0, 10 + i % 7, 8), shapely.box(20, 0, 26, 6 + i % 5)]
            bodies = [0, 3]
            if i % 2:  # body 1 on odd layers only, overlapping itself from layer to layer
                polys.append(shapely.Point(40, 10).buffer(3 + i % 3, quad_segs=4))
                bodies.append(1)
            if i == 1:  # body 2 on a layer that is never sampled
                polys.append(shapely.box(50, 50, 55, 55))
                bodies.append(2)
            return np.array(polys, dtype=object), np.array(bodies)

    lines = ObjectLabels(Layers()).define_lines()  # type: ignore[arg-type]
    assert lines[0] == "M486 T4"
    names = [line.split()[1] for line in lines[1:]]
    assert names == ["NAME=body_0", "NAME=body_1", "NAME=body_3"]
    sampled = sorted(set(np.linspace(0, 59, 24).astype(int).tolist()))
    for line, body in zip(lines[1:], (0, 1, 3), strict=True):
        parts = [p for i in sampled for p, b in zip(*Layers().layer_bodies(i), strict=True)
                 if b == body]
        hull = shapely.simplify(shapely.convex_hull(shapely.union_all(parts)), 0.2)
        ring = shapely.get_coordinates(hull.exterior)[:-1]
        polygon = ",".join(f"[{x:.3f},{y:.3f}]" for x, y in ring.tolist())
        assert line.endswith(f"POLYGON=[{polygon}]")
        assert f"CENTER={hull.centroid.x:.3f},{hull.centroid.y:.3f}" in line
