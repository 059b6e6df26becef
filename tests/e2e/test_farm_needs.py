"""The farm's pure parts: needs against printers, why a job waits, a submission's checks."""

from __future__ import annotations

import struct

import pytest
from support.paths import DATA, HOSTD, ROOT

from hostd.farm.model import Refused, footprint
from hostd.farm.needs import Needs, NeedsError, Station, misfit, parse_needs, why_waiting
from hostd.farm.records import Entry, is_job_id, new_job_id, offer, read_offer

PLA = Station("p1", "PLA", 0.4, (220.0, 220.0))
PETG_BIG = Station("p2", "PETG", 0.6, (300.0, 250.0))


def test_needs_are_read_from_the_command_line_form() -> None:
    assert parse_needs("material=PETG,nozzle=0.4,bed=220x220") == \
        Needs("PETG", 0.4, (220.0, 220.0))
    assert parse_needs("") == Needs()
    assert parse_needs(" bed = 100X50 ") == Needs(bed=(100.0, 50.0))
    for bad, words in (("colour=red", "unknown need"), ("bed=220", "WIDTHxDEPTH"),
                       ("nozzle=-1", "positive"), ("nozzle=big", "not a number"),
                       ("material", "KEY=VALUE")):
        with pytest.raises(NeedsError, match=words):
            parse_needs(bad)
    needs = Needs("PETG", 0.6, (10.0, 20.0))
    assert Needs.from_dict(needs.to_dict()) == needs


def test_a_job_fits_a_printer_with_its_material_nozzle_and_a_large_enough_bed() -> None:
    assert misfit(Needs(), PLA) is None
    assert misfit(Needs(material="pla"), PLA) is None  # names compared without case
    assert misfit(Needs(bed=(250.0, 300.0)), PETG_BIG) is None  # turned a quarter
    assert misfit(Needs(bed=(250.0, 301.0)), PETG_BIG) is not None
    assert misfit(Needs("PETG", 0.4, (230.0, 10.0)), PLA) == \
        "needs PETG (it has PLA loaded), a 230x10 mm bed (its bed is 220x220)"
    assert misfit(Needs(nozzle_mm=0.6), PLA) == "needs a 0.6 mm nozzle (it has 0.4 mm)"


def test_a_waiting_job_says_why_no_printer_takes_it() -> None:
    assert why_waiting(Needs(), []) == "no printer is taking farm jobs"
    assert why_waiting(Needs(material="ABS"), [PLA, PETG_BIG]) == \
        "needs ABS: no printer has it loaded"
    assert why_waiting(Needs(nozzle_mm=0.8, bed=(400.0, 10.0)), [PLA, PETG_BIG]) == \
        ("needs a 0.8 mm nozzle: no printer has one; needs a 400x10 mm bed: no printer's "
         "is that large")
    # each need is met by some printer, all of them by none
    assert why_waiting(Needs(material="PLA", nozzle_mm=0.6), [PLA, PETG_BIG]) == \
        "needs PLA, a 0.6 mm nozzle: no printer has all of it together"
    assert why_waiting(Needs(material="PETG"), [PLA, PETG_BIG]) == \
        "waiting for a free printer that fits (p2)"


def test_a_submission_must_be_an_stl_within_the_limit() -> None:
    cube = (DATA / "cube20_xyz.stl").read_bytes()
    width, depth = footprint("cube.stl", cube, 10**9)
    assert width == pytest.approx(20.0, abs=0.01)
    assert depth == pytest.approx(20.0, abs=0.01)
    ascii_stl = (b"solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 30 0 0\n"
                 b"vertex 0 12.5 0\nendloop\nendfacet\nendsolid t\n")
    assert footprint("t.stl", ascii_stl, 10**6) == (30.0, 12.5)
    for name, data, limit, words in (
        ("cube.stl", cube, len(cube) - 1, "over the farm's limit"),
        ("cube.obj", cube, 10**9, "not an STL file"),
        ("empty.stl", b"", 10**9, "empty"),
        ("cut.stl", cube[:-7], 10**9, "not an STL file"),
        ("words.stl", b"solid nothing here\nendsolid\n", 10**9, "not an STL file"),
    ):
        with pytest.raises(Refused, match=words):
            footprint(name, data, limit)
    header = b"\0" * 80 + struct.pack("<I", 1)
    nan = struct.pack("<12fH", 0, 0, 1, float("nan"), 0, 0, 1, 0, 0, 0, 1, 0, 0)
    with pytest.raises(Refused, match="finite"):
        footprint("nan.stl", header + nan, 10**9)


def test_entries_and_offers_round_trip() -> None:
    job_id = new_job_id()
    assert is_job_id(job_id)
    assert not is_job_id("fj-XYZ")
    entry = Entry(id=job_id, name="a.stl", model="ab" * 32, size=3, needs={"material": "PLA"})
    assert Entry.from_bytes(entry.to_bytes()) == entry
    assert read_offer(offer(job_id, 4)) == (job_id, 4)
    with pytest.raises(ValueError):  # noqa: PT011 - the message is json's own
        read_offer(b"[]")
    with pytest.raises(ValueError):  # noqa: PT011
        read_offer(b'{"id": 3, "generation": 1}')


def test_the_material_is_changed_at_run_time_with_the_config(tmp_path) -> None:
    import subprocess

    from hostd.config import load_config
    from hostd.farm.loaded import loaded_material

    config_file = tmp_path / "hostd.toml"
    config_file.write_text('[printer]\nmaterial = "PLA"\n[state]\nfolder = "var"\n')
    config = load_config(config_file, cwd=tmp_path)
    assert loaded_material(config) == "PLA"
    subprocess.run([*HOSTD, "farm", "--config", str(config_file), "material", "PETG"],
                   check=True, capture_output=True, timeout=30, cwd=tmp_path,
                   env={"PYTHONPATH": str(ROOT)})
    assert loaded_material(config) == "PETG"
    refused = subprocess.run([*HOSTD, "farm", "material", "PETG"], capture_output=True,
                             text=True, timeout=30, cwd=tmp_path)
    assert refused.returncode == 2
    assert "material needs --config" in refused.stderr


def test_the_fleet_views_farm_lines_put_failures_first_and_leave_printed_jobs_out() -> None:
    from tui.fleet_farm import farm_lines, farm_summary

    rows = [{"id": f"fj-{i:010x}", "state": state, "printer": printer, "reason": reason,
             "name": "a.stl"}
            for i, (state, printer, reason) in enumerate([
                ("waiting", None, "needs ABS: no printer has it loaded"),
                ("printed", "p1", None),
                ("taken", "p2", None),
                ("failed", "p3", "not watertight [after repair]"),
                ("interrupted", "p4", "interrupted on p4 after layer 3"),
                ("waiting", None, "waiting for a free printer that fits (p1)"),
            ])]
    lines = farm_lines(rows, limit=4)
    states = [line.split("]", 1)[1].split("[/]")[0].strip() for line in lines[:4]]
    assert states == ["failed", "interrupted", "printing", "waiting"]
    assert "fj-0000000003  a.stl on p3: not watertight \\[after repair]" in lines[0]
    assert lines[4] == "[dim]... and 1 more[/]"
    assert all("fj-0000000001" not in line for line in lines)  # printed: counted only
    summary = farm_summary(rows)
    for part in ("failed[/] 1", "printing[/] 1", "waiting[/] 2", "printed[/] 1"):
        assert part in summary
