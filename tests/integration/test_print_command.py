"""`hostd print`: a G-code file or an STL streamed to the simulated printer, exactly."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.link.protocol import strip_comment
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig
from hostd.app.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
INTERNAL = ("M110", "M115", "M503", "M155", "M105")


def _job(executed: list[str]) -> list[str]:
    return [c for c in executed if c.split(" ", 1)[0] not in INTERNAL]


def _instant() -> SimulatorConfig:
    return SimulatorConfig(time_scale=0.0, baud=0, boot_delay_s=0.0)


def test_prints_a_gcode_file_exactly(tmp_path, capsys):
    path = tmp_path / "part.gcode"
    body = ["; header", "G28", "G1 Z0.2 F600 ; first layer", "",
            *(f"G1 X{i % 50}.5 Y{i // 50}.25 E0.01" for i in range(400)), "M84"]
    path.write_text("\n".join(body) + "\n")
    with SimulatedPrinter(_instant()) as sim:
        code = main(["print", str(path), "--port", sim.path, "--baud", "250000"])
        executed = list(sim.executed)
    assert code == 0
    expected = [strip_comment(line) for line in body if strip_comment(line)]
    assert _job(executed) == expected
    err = capsys.readouterr().err
    assert "100.0%" in err
    assert f"done: {len(expected)} lines" in err


def test_prints_an_stl_sliced_just_in_time(capsys):
    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

    model = DATA / "cube20_xyz.stl"
    plan = SlicePlan.from_file(str(model), SliceSettings(), (220.0, 220.0, 250.0))
    expected = [strip_comment(x) for x in plan.start_gcode() if strip_comment(x)]
    for i in range(plan.layer_count):
        expected += [strip_comment(x) for x in plan.layer_gcode(i) if strip_comment(x)]
    expected += [strip_comment(x) for x in plan.end_gcode() if strip_comment(x)]
    with SimulatedPrinter(_instant()) as sim:
        code = main(["print", str(model), "--port", sim.path, "--quiet"])
        executed = list(sim.executed)
    assert code == 0
    assert _job(executed) == expected
    assert "done:" in capsys.readouterr().err


def test_port_sim_runs_the_in_process_simulator(tmp_path, capsys):
    path = tmp_path / "tiny.gcode"
    path.write_text("G28\nG1 X1 Y1\nG1 X2 Y2\n")
    assert main(["print", str(path), "--port", "sim", "--baud", "0", "--time-scale", "0"]) == 0
    assert "done: 3 lines" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "content", "port", "message"),
    [
        ("missing.gcode", None, "sim", "no such file"),
        ("notes.txt", "G28\n", "sim", "not a G-code file"),
        ("part.gcode", "G28\n", "/nonexistent/ttyUSB9", "cannot open"),
    ],
)
def test_bad_input_exits_2_with_a_reason(tmp_path, capsys, name, content, port, message):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    assert main(["print", str(path), "--port", port]) == 2
    assert message in capsys.readouterr().err


def test_the_progress_line_says_the_layer_printing_from_acknowledged_lines(capsys, monkeypatch):
    """`layer N of M` is the layer the printer is at (acknowledged lines), as the daemon says."""
    import bisect
    import re

    from hostd.api import layer_in_progress
    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

    monkeypatch.setenv("COLUMNS", "200")  # the whole tail of the line fits
    model = DATA / "cube20_xyz.stl"
    plan = SlicePlan.from_file(str(model), SliceSettings(), (220.0, 220.0, 250.0))
    sent = len([x for x in plan.start_gcode() if strip_comment(x)])
    ends = []  # commands sent through the end of each layer
    for i in range(plan.layer_count):
        sent += len([x for x in plan.layer_gcode(i) if strip_comment(x)])
        ends.append(sent)
    with SimulatedPrinter(SimulatorConfig(time_scale=0.002, baud=0, boot_delay_s=0.0)) as sim:
        assert main(["print", str(model), "--port", sim.path]) == 0
    drawn = re.findall(r"layer (\d+) of (\d+) (\d+) acked", capsys.readouterr().err)
    assert len(drawn) >= 3, drawn
    layers = []
    for n, m, acked in drawn:
        assert int(m) == plan.layer_count
        completed = bisect.bisect_right(ends, int(acked)) - 1  # the last layer wholly acked
        assert int(n) == layer_in_progress(completed, plan.layer_count) + 1, (n, acked)
        layers.append(int(n))
    assert layers == sorted(layers)
    assert layers[-1] == plan.layer_count
    assert any(1 < n < plan.layer_count for n in layers)  # drawn mid-print too


def test_progress_counts_a_layer_once_its_last_line_is_acknowledged():
    from hostd.app.commands.print_file import Progress

    progress = Progress("layers", 3, layer_ends=[10, 25, 40])
    seen = []
    for acked in (0, 9, 10, 24, 25, 39, 40, 44):
        progress.acked = acked
        seen.append((progress.completed_layers(), progress.layer() + 1))
    # layer 1 printing until its 10th line is acknowledged; the last stays "layer 3 of 3"
    assert seen == [(0, 1), (0, 1), (1, 2), (1, 2), (2, 3), (2, 3), (3, 3), (3, 3)]
