"""End to end: `hostd run` in a subprocess prints a dropped model on the simulated printer."""

from __future__ import annotations

import os

from support.daemon_process import sim_config
from support.gcode_lines import commands_of, executed_job_lines
from support.paths import DATA


def test_dropped_models_print_exactly_once_in_order_and_bad_ones_fail(daemon) -> None:
    hostd = daemon(sim_config(time_scale=0.0))
    failed = hostd.jobs / "failed"
    done = hostd.jobs / "done"

    hostd.drop(DATA / "bad_triangle_soup.stl", "soup.stl")
    hostd.drop(b"", "empty.stl")
    hostd.drop(os.urandom(3000), "noise.stl")
    hostd.wait_for(lambda: len(list(failed.glob("*.error.txt"))) == 3, 30, "three failures")
    for name in ("soup", "empty", "noise"):
        assert (failed / f"{name}.stl").exists()
        assert (failed / f"{name}.error.txt").read_text().strip(), name
    assert "empty (0 bytes)" in (failed / "empty.error.txt").read_text()

    hostd.drop(DATA / "dogbone_100x30x5.stl", "dogbone.stl")
    hostd.wait_for(lambda: (done / "dogbone.summary.txt").exists(), 60, "the dogbone in done/")
    assert (done / "dogbone.stl").read_bytes() == (DATA / "dogbone_100x30x5.stl").read_bytes()

    gcode = commands_of(done / "dogbone.gcode")
    executed = executed_job_lines(hostd.state / "simulator-executed.log")
    assert len(gcode) > 1000
    assert executed == gcode  # every line once, in order, nothing else
    text = (done / "dogbone.gcode").read_text()
    assert text.startswith(";")
    assert ";LAYER:0\n" in text
    assert ";LAYER_COUNT:" in text

    log = hostd.log()
    assert "layer 25/25, 100.0 %" in log
    assert "ETA" in log
    assert hostd.stop() == 0
    assert not (hostd.state / "hostd.sock").exists()
    assert list(hostd.jobs.glob("*.stl")) == []


def test_a_dropped_gcode_file_is_printed_as_is(daemon, tmp_path) -> None:
    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

    plan = SlicePlan.from_file(DATA / "cube20_xyz.stl", SliceSettings())
    lines = ["; made elsewhere", *plan.start_gcode()]
    for index in range(plan.layer_count):
        lines += plan.layer_gcode(index)
    lines += plan.end_gcode()
    source = tmp_path / "made.gcode"
    source.write_text("\r\n".join(lines) + "\r\n")  # CRLF, as some slicers write
    hostd = daemon(sim_config(time_scale=0.0))
    hostd.drop(source, "made.gcode")
    done = hostd.jobs / "done"
    hostd.wait_for(lambda: (done / "made.summary.txt").exists(), 60, "the G-code job done")
    assert (done / "made.gcode").read_bytes() == source.read_bytes()
    executed = executed_job_lines(hostd.state / "simulator-executed.log")
    assert executed == commands_of(source)
    assert len(executed) > 1000
    assert "layer 100/100, 100.0 %" in hostd.log()
    assert hostd.stop() == 0
