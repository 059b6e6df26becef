"""Jobs slice with the acceleration the printer reported, unless the configuration chose one."""

from __future__ import annotations

from pathlib import Path

from drivers.link.motion import parse_motion_report
from hostd.config import config_from_mapping
from hostd.printing.printermotion import motion_note
from hostd.printing.printjob import printer_settings

REPORTED = parse_motion_report(["echo:  M201 X2500.00 Y2500.00 Z100.00 E10000.00",
                                "echo:  M204 P3000.00 R3000.00 T3000.00", "ok"])
SILENT = parse_motion_report(['echo:Unknown command: "M503"', "ok"])


def test_the_reported_acceleration_is_used_when_nothing_chose_one(tmp_path: Path) -> None:
    config = config_from_mapping({"slicing": {"infill": {"density": 0.3}}}, tmp_path)
    assert config.slicing_given == frozenset({"infill.density"})
    mapping = config.slicing.to_mapping()
    settings = printer_settings(config, mapping, {"ARCS"}, REPORTED)
    assert settings.acceleration == 2500.0  # M204 P capped by M201 X and Y
    assert settings.infill_density == 0.3
    assert settings.gcode_arcs == "on"
    assert "2500 mm/s² learned from the printer" in motion_note(config, REPORTED)
    # a printer that reported nothing: the configured (default) value
    assert printer_settings(config, mapping, set(), SILENT).acceleration == 1000.0
    assert printer_settings(config, mapping, set()).acceleration == 1000.0
    assert "printer reported none" in motion_note(config, SILENT)


def test_an_acceleration_chosen_in_the_config_or_the_job_is_kept(tmp_path: Path) -> None:
    chosen = config_from_mapping({"slicing": {"acceleration": 1000.0}}, tmp_path)
    settings = printer_settings(chosen, chosen.slicing.to_mapping(), set(), REPORTED)
    assert settings.acceleration == 1000.0  # set explicitly, even to the default
    assert "from [slicing] (the printer reported 2500)" in motion_note(chosen, REPORTED)
    plain = config_from_mapping({}, tmp_path)
    job = {**plain.slicing.to_mapping(), "acceleration": 800.0}  # its NAME.toml's
    assert printer_settings(plain, job, set(), REPORTED).acceleration == 800.0
