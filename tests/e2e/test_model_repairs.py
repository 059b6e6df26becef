"""Repairs and refusals said plainly: winding fixed without heavy imports, ASCII files read as
other slicers read them, repairs in the job's summary and events, and `slice --profile`."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import trimesh
from support.daemon_process import sim_config
from support.paths import DATA

from hostd.api import ControlClient
from slicer.errors import ModelError
from slicer.input.mesh import prepare, read_stl
from slicer.input.repair import fix_winding, winding_flips

BED = (200.0, 200.0, 200.0)


def write_binary(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    tri = np.asarray(vertices, dtype="<f4")[faces]
    rec = np.zeros(len(faces), dtype=[("n", "<f4", (3,)), ("c", "<f4", (3, 3)), ("a", "<u2")])
    rec["c"] = tri
    path.write_bytes(b"\0" * 80 + np.uint32(len(faces)).tobytes() + rec.tobytes())
    return path


def ascii_text(mesh: trimesh.Trimesh, endsolid: bool = True) -> str:
    text = trimesh.exchange.stl.export_stl_ascii(mesh)
    if not endsolid:
        text = text[: text.rindex("endsolid")]
    return text


def boxes(*specs: tuple[tuple[float, float, float], tuple[float, float, float]]):
    """Separate box shells, (vertices, faces): ``specs`` are (size, min corner)."""
    vs, fs, n = [], [], 0
    for size, corner in specs:
        b = trimesh.creation.box(size)
        vs.append(b.vertices + np.asarray(size) / 2 + corner)
        fs.append(b.faces + n)
        n += len(b.vertices)
    return np.concatenate(vs), np.concatenate(fs)


def test_winding_fix_makes_every_edge_run_both_ways():
    sphere = trimesh.creation.icosphere(4)
    faces = sphere.faces.copy()
    rng = np.random.default_rng(1)
    flip = rng.random(len(faces)) < 0.3
    faces[flip] = faces[flip][:, ::-1]
    fixed, turned = fix_winding(sphere.vertices, faces)
    assert turned == flip.sum()  # the majority kept: exactly the flipped faces turned back
    assert np.array_equal(fixed, sphere.faces)
    again, none = fix_winding(sphere.vertices, fixed)
    assert none == 0
    assert again is fixed


def test_winding_patches_are_set_apart():
    v, f = boxes(((10, 10, 10), (0, 0, 0)), ((5, 5, 5), (20, 0, 0)))
    f = f.copy()
    f[12:] = f[12:, ::-1]  # the second box wound inwards throughout: consistent on its own
    flip, root = winding_flips(f, len(v))
    assert not flip.any()
    assert len(np.unique(root)) == 2


def test_bad_winding_repair_imports_neither_trimesh_nor_scipy(tmp_path):
    sphere = trimesh.creation.icosphere(3, radius=10)
    faces = sphere.faces.copy()
    faces[::3] = faces[::3, ::-1]
    path = write_binary(tmp_path / "bad.stl", sphere.vertices, faces)
    code = (
        "import sys\n"
        "from slicer.plan import SlicePlan\n"
        "from slicer.settings import SliceSettings\n"
        f"plan = SlicePlan.from_file({str(path)!r}, SliceSettings())\n"
        "plan.layer_gcode(0)\n"
        "print(plan.warnings_so_far)\n"
        "print(sorted(m for m in ('trimesh', 'scipy') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120).stdout.splitlines()
    assert "fixed inconsistent face winding" in out[0]
    assert out[1] == "[]"


def test_ascii_without_endsolid_reads_like_the_whole_file(tmp_path):
    box = trimesh.creation.box((20, 10, 5))
    whole = tmp_path / "whole.stl"
    cut = tmp_path / "no_end.stl"
    whole.write_text(ascii_text(box))
    cut.write_text(ascii_text(box, endsolid=False))
    vw, fw = read_stl(whole)
    vc, fc = read_stl(cut)
    assert len(fc) == 12
    assert np.array_equal(vw, vc)
    assert np.array_equal(fw, fc)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n",
         "facet 1 (line 2) has 2 vertices, not 3 (the file ends inside it"),
        ("solid a\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 x\n"
         "vertex 0 1 0\nendloop\nendfacet\n", "line 5 has a coordinate that is not a number"),
        ("solid a\nendsolid a\n", "no facets"),
    ],
)
def test_ascii_refusals_name_what_is_wrong(tmp_path, text, words):
    path = tmp_path / "bad.stl"
    path.write_text(text)
    with pytest.raises(ModelError, match=None) as err:
        read_stl(path)
    assert words in str(err.value)


def test_cubes_sharing_an_edge_are_reported():
    v, f = boxes(((20, 20, 20), (0, 0, 0)), ((20, 20, 20), (20, 20, 0)))
    # share the corners of the common edge, as an exporter writing one mesh does
    from slicer.input.mesh import merge_corners

    v, f = merge_corners(v[f].reshape(-1, 3))
    placed = prepare(v, f, BED)
    assert any("1 edge is shared by more than two faces" in w for w in placed.warnings)


def collect_events(socket: Path, kinds: set[str], out: list[dict], ready: threading.Event,
                   until: int) -> None:
    async def run() -> None:
        async with ControlClient(str(socket)) as client:
            ready.set()
            async for item in client.subscribe():
                event = item.get("event")
                if event and event.get("event") in kinds:
                    out.append(event)
                    if sum(e["event"] == "done" for e in out) >= until:
                        return

    asyncio.run(asyncio.wait_for(run(), 120))


def test_repairs_go_into_the_summary_and_the_events(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.0))
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    events: list[dict] = []
    ready = threading.Event()
    listener = threading.Thread(target=collect_events, daemon=True,
                                args=(socket, {"repaired", "done"}, events, ready, 2))
    listener.start()
    assert ready.wait(10)
    v, f = boxes(((20, 20, 10), (0, 0, 0)), ((20, 20, 10), (10, 5, 0)))
    hostd.drop(write_binary(tmp_path / "o.stl", v, f), "overlapping.stl")
    hostd.drop((DATA / "cube20_xyz.stl").read_bytes(), "good.stl")
    done = hostd.jobs / "done"
    hostd.wait_for(lambda: (done / "good.summary.txt").exists(), 120, "both jobs")
    listener.join(30)
    summary = (done / "overlapping.summary.txt").read_text()
    assert "model: self-intersecting or overlapping outlines made valid" in summary
    assert "model:" not in (done / "good.summary.txt").read_text()
    repaired = [e for e in events if e["event"] == "repaired"]
    assert repaired
    assert all(e["name"] == "overlapping.stl" for e in repaired)
    assert any("overlapping outlines" in e["message"] for e in repaired)


def test_slice_profile_prints_every_stage(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "hostd.app.cli", "slice", str(DATA / "featuretype_mm.stl"),
         "-o", str(tmp_path / "f.gcode"), "--quiet", "--profile"],
        capture_output=True, text=True, check=True, timeout=300,
    ).stdout
    stages = {line[:32].strip(): line[32:].split() for line in out.splitlines()[1:]}
    for stage in ("read", "check and repair", "outlines", "skins", "walls", "infill",
                  "ordering", "G-code", "total"):
        assert stage in stages, out
    for stage in ("read", "outlines", "walls", "infill", "ordering", "G-code"):
        assert int(stages[stage][2]) > 0, out  # its timer saw the stage run
    total = float(stages["total"][0])
    parts = sum(float(v[0]) for k, v in stages.items() if k not in ("total", "stage"))
    assert abs(parts - total) < 0.01 * total + 0.002
