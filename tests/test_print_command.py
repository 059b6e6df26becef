"""`hostd print`: a G-code file or an STL streamed to the simulated printer, exactly."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.protocol import strip_comment
from drivers.simulator import SimulatedPrinter, SimulatorConfig
from hostd.cli import main

DATA = Path(__file__).parent / "data"
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
