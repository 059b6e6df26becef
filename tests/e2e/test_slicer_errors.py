"""Bad input: each refused model raises ModelError with a specific reason; the CLI exits 2."""

from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from support.slicer_helpers import DATA, box_stl, write_mesh

from slicer.errors import ModelError
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

HOSTD = [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]


def _plan(path, bed=(220.0, 220.0, 250.0)):
    return SlicePlan.from_file(path, SliceSettings(), bed)


def test_empty_file(tmp_path) -> None:
    p = tmp_path / "e.stl"
    p.write_bytes(b"")
    with pytest.raises(ModelError, match="empty file"):
        _plan(p)


def test_not_an_stl(tmp_path) -> None:
    p = tmp_path / "t.stl"
    p.write_text("this is a shopping list\n" * 20)
    with pytest.raises(ModelError, match="not an STL"):
        _plan(p)


def test_truncated_binary(tmp_path) -> None:
    good = (DATA / "cube20_xyz.stl").read_bytes()
    p = tmp_path / "cut.stl"
    p.write_bytes(good[: len(good) // 2])
    with pytest.raises(ModelError):
        _plan(p)


def test_non_finite_coordinates(tmp_path) -> None:
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, float("nan")]], dtype="<f4")
    body = struct.pack("<12f", 0, 0, 1, *tri.ravel()) + b"\0\0"
    p = tmp_path / "nan.stl"
    p.write_bytes(b"\0" * 80 + struct.pack("<I", 1) + body)
    with pytest.raises(ModelError, match="non-finite"):
        _plan(p)


def test_triangle_soup_is_not_watertight() -> None:
    with pytest.raises(ModelError, match="not watertight after repair: 300 open edges"):
        _plan(DATA / "bad_triangle_soup.stl")


def test_bigger_than_the_bed(tmp_path) -> None:
    with pytest.raises(ModelError, match="bigger than the bed"):
        _plan(box_stl(tmp_path / "big.stl", (250, 20, 5)))


def test_zero_volume(tmp_path) -> None:
    flat = trimesh.Trimesh(
        vertices=[[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]],
        faces=[[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]],
        process=False,
    )
    with pytest.raises(ModelError, match=r"zero volume|degenerate|not watertight"):
        _plan(write_mesh(flat, tmp_path / "flat.stl"))


def test_ascii_stl_loads(tmp_path) -> None:
    mesh = trimesh.creation.box(extents=(10, 10, 3))
    p = tmp_path / "ascii.stl"
    p.write_text(trimesh.exchange.stl.export_stl_ascii(mesh))
    plan = _plan(p)
    assert plan.layer_count == 15
    assert plan.warnings == []


def test_cli_exit_codes(tmp_path) -> None:
    out = tmp_path / "o.gcode"
    ok = subprocess.run(
        [
            *HOSTD,
            "slice",
            str(DATA / "cube20_xyz.stl"),
            "-o",
            str(out),
            "--quiet",
            "--set",
            "infill.density=0.3",
            "--jobs",
            "2",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert ok.returncode == 0, ok.stderr
    assert "100 layers" in ok.stdout
    assert out.read_text().startswith(";FLAVOR:Marlin")
    bad = subprocess.run(
        [
            *HOSTD,
            "slice",
            str(DATA / "bad_triangle_soup.stl"),
            "-o",
            str(tmp_path / "x.gcode"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert bad.returncode == 2
    assert "not watertight" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
    unknown = subprocess.run(
        [
            *HOSTD,
            "slice",
            str(DATA / "cube20_xyz.stl"),
            "-o",
            str(tmp_path / "y.gcode"),
            "--set",
            "infill.colour=3",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert unknown.returncode == 2
    assert "infill.colour" in unknown.stderr
    no_jobs = subprocess.run([*HOSTD, "slice", str(DATA / "cube20_xyz.stl"), "-o",
                              str(tmp_path / "z.gcode"), "--jobs", "0"],
                             capture_output=True, text=True, check=False)
    assert no_jobs.returncode == 2
    assert "--jobs: 0: at least 1 process slices" in no_jobs.stderr


def test_cli_reads_slicing_and_bed_from_the_config(tmp_path) -> None:
    cfg = tmp_path / "hostd.toml"
    cfg.write_text("[printer]\nbed = [180, 160, 100]\n[slicing]\nperimeters = 3\n")
    out = tmp_path / "c.gcode"
    run = subprocess.run(
        [
            *HOSTD,
            "slice",
            str(DATA / "cube20_xyz.stl"),
            "-o",
            str(out),
            "--quiet",
            "--config",
            str(cfg),
            "--set",
            "infill.density=0.4",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    text = out.read_text()
    assert "; infill = linear 0.4" in text
    xs = [
        float(w[1:])
        for line in text.splitlines()
        if line.startswith("G1 ")
        for w in line.split()
        if w.startswith("X")
    ]
    assert min(xs) >= 80
    assert max(xs) <= 100
    assert text.count(";TYPE:WALL-INNER") > 0
    bad = tmp_path / "bad.toml"
    bad.write_text("[slicing]\nperimeters = -1\n")
    refused = subprocess.run(
        [*HOSTD, "slice", str(DATA / "cube20_xyz.stl"), "-o", str(out), "--config", str(bad)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert refused.returncode == 2
    assert "slicing.perimeters" in refused.stderr
