"""`hostd tailor` and the rebuilt prints: a solid print as stiff as the model, three G-codes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh
from support.slicer_helpers import write_mesh

from slicer.fea.predict import predict_moduli
from slicer.output.gcodefile import write_gcode
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

ROOT = Path(__file__).resolve().parents[2]
HOSTD = [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]
BED = (220.0, 220.0, 250.0)
# a small flat specimen pulled along x: 60 x 12 x 3 mm, the left 8 mm held
SPECIMEN = """
[[fixed]]
box = [[0, 0, 0], [8, 12, 3]]
[[force]]
box = [[52, 0, 0], [60, 12, 3]]
newtons = [300, 0, 0]
"""
FLAT = {"layer_height": 0.3, "first_layer_height": 0.3, "top_layers": 1, "bottom_layers": 1,
        "perimeters": 1, "fea.mesh_size": 1.0}


def specimen(folder: Path) -> Path:
    """``bar.stl`` and ``bar.load.toml`` in ``folder``; returns the STL."""
    folder.mkdir(parents=True, exist_ok=True)
    bar = trimesh.creation.box((60.0, 12.0, 3.0))
    bar.apply_translation([30.0, 6.0, 1.5])
    (folder / "bar.load.toml").write_text(SPECIMEN)
    return write_mesh(bar, folder / "bar.stl")


def test_a_solid_print_rebuilt_is_as_stiff_as_the_solid_model(tmp_path: Path) -> None:
    stl = specimen(tmp_path)
    settings = SliceSettings.from_mapping({**FLAT, "infill.density": 1.0})
    plan = SlicePlan.from_file(stl, settings, BED)
    write_gcode(plan, tmp_path / "solid.gcode", workers=1)
    sparse = plan.with_settings(SliceSettings.from_mapping({**FLAT, "infill.density": 0.2}))
    write_gcode(sparse, tmp_path / "sparse.gcode", workers=1)
    solid, printed, thin = predict_moduli(
        stl, tmp_path / "bar.load.toml", settings, plan.bounds,
        {"solid print": tmp_path / "solid.gcode", "sparse": tmp_path / "sparse.gcode"},
    )
    assert solid.modulus_mpa == pytest.approx(2200.0, rel=0.05)
    # a print at infill 1 from its roads (fill and direction): the solid's modulus
    assert printed.modulus_mpa == pytest.approx(solid.modulus_mpa, rel=0.02)
    assert printed.stiffness == pytest.approx(solid.stiffness, rel=0.05)
    assert printed.fill > 0.95
    assert thin.modulus_mpa < 0.6 * solid.modulus_mpa
    assert thin.fill < 0.6


def test_tailor_writes_three_gcodes_at_equal_mass_and_the_pictures(tmp_path: Path) -> None:
    folder = tmp_path / "specimen"
    specimen(folder)
    (folder / "bar.toml").write_text(
        "".join(f"{k} = {v}\n" for k, v in FLAT.items()) + "infill.density = 0.3\n")
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT)}
    done = subprocess.run([*HOSTD, "tailor", str(folder)], capture_output=True, text=True,
                          env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    out = folder / "out"
    for name in ("linear.gcode", "stress-a.gcode", "stress-b.gcode", "fig16.png", "fig17.png"):
        assert (out / name).stat().st_size > 0, name
    report = (out / "tailor.txt").read_text()
    for variant in ("a", "b"):
        line = next(x for x in report.splitlines() if x.startswith(f"stress-{variant}.gcode: eq"))
        error = float(line.rsplit(",", 1)[1].strip().rstrip("%").strip())
        assert abs(error) < 1.0, line
    assert "Stress A" in report
    assert "Stress B" in report
    assert "vs Linear" in report
    # the report names the gage length it reads and carries the whole part's stiffness
    assert "headline (the load case's test): apparent modulus read by a 20 mm extensometer" \
        in report
    linear = next(x for x in report.splitlines() if x.strip().startswith("Linear"))
    assert "modulus at 20 / 44 mm" in linear, linear
    assert "N/mm" in linear, linear
    assert "headline vs Linear: Stress A" in report


def test_tailor_refuses_a_folder_whose_load_case_has_no_model(tmp_path: Path) -> None:
    (tmp_path / "part.load.toml").write_text(SPECIMEN)
    done = subprocess.run([*HOSTD, "tailor", str(tmp_path)], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=60)
    assert done.returncode == 2
    assert "part.load.toml: its model part.stl is missing" in done.stderr
