"""Multibody and unwelded exports as CAD tools write them: stray sheets, inlay bodies
given as loose triangles, overlapping bodies; each prints as its designer meant."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import shapely
import trimesh
from support.daemon_process import sim_config
from support.paths import DATA

from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

BED = (200.0, 200.0, 200.0)


def box(size: tuple[float, float, float], corner: tuple[float, float, float]) -> trimesh.Trimesh:
    """A closed box of ``size`` mm with its lowest corner at ``corner``."""
    b = trimesh.creation.box(size)
    b.apply_translation(np.asarray(size) / 2.0 + corner)
    return b


def stacked(*meshes: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """The meshes' vertices and faces in one array each, no vertex shared."""
    vs, fs, n = [], [], 0
    for m in meshes:
        vs.append(np.asarray(m.vertices, dtype=np.float64))
        fs.append(np.asarray(m.faces) + n)
        n += len(m.vertices)
    return np.concatenate(vs), np.concatenate(fs)


def sliced(vertices: np.ndarray, faces: np.ndarray) -> SlicePlan:
    """A plan of the mesh, every layer's G-code made once."""
    plan = SlicePlan.from_mesh(vertices, faces, SliceSettings(), bed=BED)
    for i in range(plan.layer_count):
        plan.layer_gcode(i)
    return plan


def test_a_stray_triangle_beside_a_part_does_not_stop_it():
    # one triangle 1 mm across crossing a layer: its cut is a single segment, which
    # closed on itself was a ring of two points (the real parts' crash)
    sphere = trimesh.creation.icosphere(3, radius=10.0)
    sphere.apply_translation((0.0, 0.0, 10.0))
    sheet = trimesh.Trimesh([[30, 0, 4.5], [31, 0, 4.5], [30.5, 0.5, 6.0]], [[0, 1, 2]])
    plan = sliced(*stacked(sphere, sheet))
    middle = plan.outline(plan.layer_count // 2)
    assert abs(shapely.area(middle) - np.pi * 100.0) < 0.05 * np.pi * 100.0
    assert shapely.area(plan.outline(24)) > 0  # the layer the triangle crosses prints the sphere


def plate_with_inlay(jitter: float) -> tuple[np.ndarray, np.ndarray]:
    """A 30 x 20 x 4 mm plate and a 10 x 6 x 0.4 mm inlay body set into its underside,
    written as a multibody CAD export writes them: the plate's bottom face has an
    opening where the inlay sits, the inlay is a closed body of its own, every
    inlay triangle has corners of its own, moved by up to ``jitter`` mm (corners
    that nearly meet), and the inlay's bottom is also given the other way round
    (a wall of no thickness)."""
    import manifold3d

    plate = manifold3d.Manifold.cube((30.0, 20.0, 4.0))
    inlay = manifold3d.Manifold.cube((10.0, 6.0, 0.4)).translate((10.0, 7.0, 0.0))
    pocketed = (plate - inlay).to_mesh()
    pv = np.asarray(pocketed.vert_properties)[:, :3].astype(np.float64)
    pf = np.asarray(pocketed.tri_verts).astype(np.int64)
    # keep the plate's faces except the pocket's walls and ceiling (inside the inlay's box)
    centre = pv[pf].mean(axis=1)
    inside = ((centre[:, 0] > 10.0 - 1e-9) & (centre[:, 0] < 20.0 + 1e-9)
              & (centre[:, 1] > 7.0 - 1e-9) & (centre[:, 1] < 13.0 + 1e-9)
              & (centre[:, 2] > 1e-9) & (centre[:, 2] < 0.4 + 1e-9))
    pf = pf[~inside]
    im = inlay.to_mesh()
    iv = np.asarray(im.vert_properties)[:, :3].astype(np.float64)
    tri = iv[np.asarray(im.tri_verts)]  # (n, 3, 3): every triangle its own corners
    rng = np.random.default_rng(7)
    tri = tri + rng.uniform(-jitter, jitter, tri.shape)
    bottom = np.abs(tri[:, :, 2]).max(axis=1) < 1e-3
    reversed_bottom = tri[bottom][:, ::-1]
    soup = np.concatenate([tri, reversed_bottom, tri[bottom]])
    sv = soup.reshape(-1, 3)
    sf = np.arange(len(sv)).reshape(-1, 3) + len(pv)
    return np.concatenate([pv, sv]), np.concatenate([pf, sf])


def test_an_inlay_body_of_loose_triangles_prints_as_one_solid_plate():
    vertices, faces = plate_with_inlay(jitter=2e-5)
    plan = sliced(vertices, faces)
    whole = 30.0 * 20.0
    for i in (0, 1, plan.layer_count - 1):
        outline = plan.outline(i)
        assert abs(shapely.area(outline) - whole) < 0.01 * whole, (i, shapely.area(outline))
        assert all(len(p.interiors) == 0 for p in shapely.get_parts(outline))
    words = " ".join(plan.warnings)
    assert "welded" in words, plan.warnings
    assert "given once each way" in words, plan.warnings
    plain = sliced(*stacked(box((30.0, 20.0, 4.0), (0.0, 0.0, 0.0))))
    assert plan.body_count == 1
    ours = sum(len(plan.layer_gcode(i)) for i in range(plan.layer_count))
    assert ours == sum(len(plain.layer_gcode(i)) for i in range(plain.layer_count))


def test_two_overlapping_boxes_print_as_their_union():
    a = box((20.0, 10.0, 6.0), (0.0, 0.0, 0.0))
    b = box((10.0, 20.0, 4.0), (5.0, -5.0, 0.0))
    plan = sliced(*stacked(a, b))
    assert plan.body_count == 1
    assert abs(shapely.area(plan.outline(0)) - (200.0 + 200.0 - 100.0)) < 1.0
    assert abs(shapely.area(plan.outline(plan.layer_count - 1)) - 200.0) < 1.0
    assert "2 bodies overlapped: united, printed as one" in plan.warnings, plan.warnings


def test_an_open_sheet_beside_a_box_is_named_and_left_out():
    part = box((20.0, 20.0, 10.0), (0.0, 0.0, 0.0))
    # two walls 8 mm wide and 6 mm high meeting at a corner, 40 mm away: a bent sheet
    # (closed layer by layer it would print as a triangular prism)
    corners = [[40, 0, 0], [48, 0, 0], [48, 8, 0], [40, 0, 6], [48, 0, 6], [48, 8, 6]]
    sheet = trimesh.Trimesh(corners, [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    plan = sliced(*stacked(part, sheet))
    assert plan.body_count == 1
    assert abs(shapely.area(plan.outline(10)) - 400.0) < 1.0
    assert any(w.startswith("body 2 of 2 (an open surface of 4 triangles, 8.0 x 8.0 x 6.0 mm)")
               for w in plan.warnings), plan.warnings


def write_triangles(path: Path, triangles: np.ndarray) -> Path:
    """``triangles`` (n, 3, 3) mm as a binary STL."""
    tri = np.asarray(triangles, dtype="<f4").reshape(-1, 3, 3)
    rec = np.zeros(len(tri), dtype=[("n", "<f4", (3,)), ("c", "<f4", (3, 3)), ("a", "<u2")])
    rec["c"] = tri
    path.write_bytes(b"\0" * 80 + np.uint32(len(tri)).tobytes() + rec.tobytes())
    return path


def part_and_stray_triangle() -> np.ndarray:
    """The real parts' crash in small: a sphere and one loose 1 mm triangle beside it."""
    sphere = trimesh.creation.icosphere(3, radius=10.0)
    sphere.apply_translation((0.0, 0.0, 10.0))
    stray = np.array([[[30, 0, 4.5], [31, 0, 4.5], [30.5, 0.5, 6.0]]], dtype=np.float64)
    return np.concatenate([sphere.triangles, stray])


def test_slice_says_what_it_left_out_and_never_prints_a_traceback(tmp_path):
    model = write_triangles(tmp_path / "stray.stl", part_and_stray_triangle())
    done = subprocess.run(
        [sys.executable, "-m", "hostd.app.cli", "slice", str(model),
         "-o", str(tmp_path / "s.gcode"), "--quiet"],
        capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    assert ("warning: body 2 of 2 (an open surface of 1 triangle, 1.0 x 0.5 x 1.5 mm): "
            "encloses nothing, left out") in done.stdout


def test_the_daemon_prints_the_old_crash_and_fails_only_sheets_with_a_reason(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.0))
    hostd.drop(write_triangles(tmp_path / "a.stl", part_and_stray_triangle()), "stray.stl")
    sheets = [[[0, 0, 0], [10, 0, 0], [10, 0, 5]], [[20, 0, 0], [30, 0, 0], [30, 0, 5]]]
    hostd.drop(write_triangles(tmp_path / "b.stl", np.array(sheets, dtype=float)), "sheets.stl")
    hostd.drop((DATA / "cube20_xyz.stl").read_bytes(), "good.stl")
    done, failed = hostd.jobs / "done", hostd.jobs / "failed"
    hostd.wait_for(lambda: (done / "good.summary.txt").exists(), 120, "the three jobs")
    assert "left out" in (done / "stray.summary.txt").read_text()
    reason = (failed / "sheets.error.txt").read_text()
    assert "not watertight after repair" in reason, reason
    assert "internal error" not in hostd.log()
