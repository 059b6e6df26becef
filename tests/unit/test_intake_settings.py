"""Per-job slicing settings: a field file named by a job's TOML is found beside it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from hostd.config import config_from_mapping
from hostd.jobs.intake import Intake, Rejected


def _job_settings(folder: Path, toml: str) -> dict[str, object]:
    config = config_from_mapping({}, folder)
    override = folder / "part.toml"
    override.write_text(toml, encoding="utf-8")
    return Intake._settings(SimpleNamespace(config=config), override)


def test_relative_field_file_in_a_job_toml_is_taken_from_the_job_folder(tmp_path, monkeypatch):
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "part-stress.csv").write_text("x,y,z,value\n0,0,0,1\n", encoding="utf-8")
    monkeypatch.chdir(tmp_path)  # the daemon's working directory is not the job folder
    settings = _job_settings(jobs, '[infill]\nfield = "stress"\nfile = "part-stress.csv"\n')
    assert settings["infill.file"] == str((jobs / "part-stress.csv").absolute())


def test_a_missing_field_file_rejects_the_job_naming_the_key(tmp_path):
    with pytest.raises(Rejected, match=r"part.toml: infill.file: no such file: gone.csv"):
        _job_settings(tmp_path, '[infill]\nfield = "stress"\nfile = "gone.csv"\n')


def test_job_toml_without_a_field_file_keeps_the_configured_one(tmp_path):
    config = config_from_mapping({"slicing": {"infill": {"file": "fields/s.csv"}}}, tmp_path)
    override = tmp_path / "part.toml"
    override.write_text("infill.density = 0.3\n", encoding="utf-8")
    settings = Intake._settings(SimpleNamespace(config=config), override)
    assert settings["infill.file"] == str(tmp_path / "fields" / "s.csv")
    assert settings["infill.density"] == 0.3


def test_relative_field_file_in_the_config_is_anchored_at_load(tmp_path):
    config = config_from_mapping({"slicing": {"infill.file": "s.csv"}}, tmp_path)
    assert config.slicing.infill_file == str(tmp_path / "s.csv")
    assert config_from_mapping({}, tmp_path).slicing.infill_file == ""


def test_a_job_toml_may_carry_a_material_table_over_the_configured_material(tmp_path):
    config = config_from_mapping({"material": {"density_g_cm3": 1.24}}, tmp_path)
    override = tmp_path / "part.toml"
    override.write_text("infill.density = 0.3\n\n[material]\nyoungs_modulus_mpa = 1800\n"
                        "density_g_cm3 = 1.04\n", encoding="utf-8")
    settings = Intake._settings(SimpleNamespace(config=config), override)
    assert settings["fea.youngs_modulus_mpa"] == 1800
    assert settings["filament_density"] == 1.04
    assert settings["fea.poisson_ratio"] == config.slicing.fea_poisson_ratio
    assert settings["infill.density"] == 0.3


@pytest.mark.parametrize(("toml", "message"), [
    ("filament_density = 1.1\n[material]\ndensity_g_cm3 = 1.04\n",
     r"part.toml: material.density_g_cm3: also given as slicing setting filament_density"),
    ("[material]\nhardness = 3\n", r"part.toml: material.hardness: unknown material key"),
    ("[material]\npoisson_ratio = 0.9\n", r"part.toml: material.poisson_ratio: "),
    ('material = "ABS"\n', r"part.toml: material: must be a \[material\] table"),
])
def test_a_wrong_material_table_rejects_the_job_naming_the_key(tmp_path, toml, message):
    with pytest.raises(Rejected, match=message):
        _job_settings(tmp_path, toml)


@pytest.mark.parametrize("example", ["dogbone", "bracket"])
def test_the_examples_material_is_read_by_the_daemon(example):
    folder = Path(__file__).resolve().parents[2] / "examples" / example
    config = config_from_mapping({}, folder)
    settings = Intake._settings(SimpleNamespace(config=config), folder / f"{example}.toml")
    assert (settings["fea.youngs_modulus_mpa"], settings["fea.poisson_ratio"],
            settings["filament_density"]) == (2200, 0.35, 1.04)
