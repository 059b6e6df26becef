"""The simulated printer speaks Marlin's line protocol: numbering, checksums, replies."""

from __future__ import annotations

import re

import pytest
from support.simhost import Host, stream

from drivers.link.protocol import checksum, frame
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig

TEMPS = re.compile(r"^ok T:\d+\.\d\d /\d+\.\d\d B:\d+\.\d\d /\d+\.\d\d @:\d+ B@:\d+$")


@pytest.fixture
def sim():
    with SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0)) as printer:
        yield printer


@pytest.fixture
def host(sim):
    link = Host(sim.start())
    link.wait_start()
    link.read_until(lambda line: line.startswith("echo: Free"))
    yield link
    link.close()


def test_start_banner_when_the_port_opens(sim):
    link = Host(sim.start())
    try:
        assert link.wait_start() == ["start"]
    finally:
        link.close()


def test_numbered_lines_in_sequence_are_executed(host, sim):
    assert host.command(1, "G28") == ["echo:busy: processing", "ok"]  # homing takes 3 s
    assert host.command(2, "G1 X10 Y10 F3000") == ["ok"]
    assert sim.executed == ["G28", "G1 X10 Y10 F3000"]
    assert sim.last_line == 2


def test_line_number_error_is_reported_before_checksum(host, sim):
    host.command(1, "G28")
    host.write(b"N3 G1 X1*0\n")  # wrong number and wrong checksum
    assert host.read_until(lambda line: line.startswith("ok")) == [
        "Error:Line Number is not Last Line Number+1, Last Line: 1",
        "Resend: 2",
        "ok",
    ]
    assert sim.executed == ["G28"]


def test_checksum_mismatch(host, sim):
    body = "N1 G1 X5"
    host.write(f"{body}*{(checksum(body) + 1) % 256}\n".encode())
    assert host.read_until(lambda line: line.startswith("ok")) == [
        "Error:checksum mismatch, Last Line: 0",
        "Resend: 1",
        "ok",
    ]
    assert sim.executed == []


def test_numbered_line_without_checksum(host, sim):
    host.write(b"N1 G1 X5\n")
    assert host.read_until(lambda line: line.startswith("ok")) == [
        "Error:No Checksum with line number, Last Line: 0",
        "Resend: 1",
        "ok",
    ]
    assert sim.executed == []


def test_already_executed_line_is_rejected_not_repeated(host, sim):
    host.command(1, "G1 X1")
    host.command(2, "G1 X2")
    lines = host.command(2, "G1 X2")
    assert lines[-2:] == ["Resend: 3", "ok"]
    assert lines[0] == "Error:Line Number is not Last Line Number+1, Last Line: 2"
    assert sim.executed == ["G1 X1", "G1 X2"]


def test_error_drains_the_receive_buffer(host, sim):
    bad = b"N1 G1 X1*0\n"
    host.write(bad + frame(2, "G1 X2"))  # both in the buffer when the error is found
    host.read_until(lambda line: line.startswith("ok"))
    assert host.readline(0.3) is None  # N2 was thrown away with the buffer, never answered
    assert sim.executed == []


def test_m110_sets_the_last_line(host, sim):
    assert host.command(7, "M110 N41") == ["ok"]  # parameter wins over the line's own N
    assert host.command(42, "G1 X1") == ["ok"]
    host.write(b"M110 N99\n")
    host.read_until(lambda line: line.startswith("ok"))
    assert host.command(100, "G1 X2") == ["ok"]
    assert sim.executed == ["M110 N41", "G1 X1", "M110 N99", "G1 X2"]


def test_unnumbered_lines_are_executed_without_checks(host, sim):
    host.write(b"G1 X3\n")
    assert host.read_until(lambda line: line.startswith("ok")) == ["ok"]
    host.write(b"  G1 X4 ; comment\n")
    assert host.read_until(lambda line: line.startswith("ok")) == ["ok"]
    assert sim.executed == ["G1 X3", "G1 X4"]
    assert sim.last_line == 0


def test_blank_and_comment_lines_get_no_answer(host, sim):
    host.write(b"\n; just a comment\n")
    assert host.readline(0.3) is None


def test_unknown_command(host, sim):
    lines = host.command(1, "M9999")
    assert lines == ['echo:Unknown command: "M9999"', "ok"]


def test_m105_reports_temperatures(host):
    (line,) = host.command(1, "M105")
    assert TEMPS.match(line), line


def test_m115_capabilities(host):
    lines = host.command(1, "M115")
    assert lines[0].startswith("FIRMWARE_NAME:Marlin ")
    assert "PROTOCOL_VERSION:" in lines[0]
    assert "EXTRUDER_COUNT:1" in lines[0]
    caps = dict(line[4:].rsplit(":", 1) for line in lines[1:-1])
    assert caps["AUTOREPORT_TEMP"] == "1"
    assert caps["EMERGENCY_PARSER"] == "1"
    assert caps["ADVANCED_OK"] == "0"
    assert lines[-1] == "ok"


def test_advanced_ok_reports_line_planner_and_queue():
    config = SimulatorConfig(time_scale=0.0, baud=0, advanced_ok=True, emergency_parser=False)
    with SimulatedPrinter(config) as sim:
        link = Host(sim.start())
        link.wait_start()
        lines = link.command(1, "M115")
        assert "Cap:ADVANCED_OK:1" in lines
        assert "Cap:EMERGENCY_PARSER:0" in lines
        assert lines[-1] == "ok N1 P16 B3"  # the running command holds its slot
        assert link.command(2, "G1 X10 F600") == ["ok N2 P15 B3"]
        link.write(b"M400\n")
        assert link.readline() == "ok P16 B3"  # unnumbered: no N; the planner ran empty
        link.close()


def test_marlin_20_mode_answers_an_error_without_ok():
    with SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0, ok_after_resend=False)) as sim:
        link = Host(sim.start())
        link.wait_start()
        link.write(b"N5 G1 X1*0\n")
        lines = link.read_until(lambda line: line.startswith("Resend"))
        assert lines[-2:] == ["Error:Line Number is not Last Line Number+1, Last Line: 0",
                              "Resend: 1"]
        assert link.readline(0.3) is None
        link.close()


def test_clean_run_log_equals_the_commands(tmp_path):
    log = tmp_path / "executed.log"
    commands = [f"G1 X{i % 50} Y{(i * 3) % 50} E{i * 0.02:.2f} F6000" for i in range(2000)]
    with SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0, log_path=str(log))) as sim:
        link = Host(sim.start())
        link.wait_start()
        # no ok is lost on a clean run: a long wait before a resend, so that a loaded
        # machine's slow answer is not taken for a lost one (a resend is an error)
        stream(link, commands, ok_timeout=10.0)
        link.close()
        executed = [c for c in sim.executed if not c.startswith("M110")]
        assert executed == commands
        assert sim.stats().errors == 0
    logged = [c for c in log.read_text().splitlines() if not c.startswith("M110")]
    assert logged == commands


def test_m112_halts_the_printer(host, sim):
    host.command(1, "G1 X1")
    host.send(2, "M112")
    assert host.read_until(lambda line: line.startswith("Error")) == [
        "Error:Printer halted. kill() called!"
    ]
    host.send(3, "G1 X2")
    assert host.readline(0.3) is None
    assert sim.executed == ["G1 X1", "M112"]


def test_emergency_parser_stops_a_heating_wait_at_once():
    with SimulatedPrinter(SimulatorConfig(time_scale=1.0, baud=0)) as sim:
        link = Host(sim.start())
        link.wait_start()
        link.send(1, "M109 S210")
        link.read_until(lambda line: "W:" in line)  # waiting; the queue is not being read
        link.send(2, "M108")
        assert link.read_until(lambda line: line.startswith("ok"))[-1] == "ok"  # M109 ends
        link.send(3, "M104 S0")
        link.read_until(lambda line: line.startswith("ok"))
        link.send(4, "M109 S210")
        link.read_until(lambda line: "W:" in line)
        link.send(5, "M112")
        link.read_until(lambda line: line == "Error:Printer halted. kill() called!", 2.0)
        assert sim.executed[-1] == "M112"
        link.close()


def test_reopening_the_port_resets_the_printer(host, sim):
    host.command(1, "G1 X1")
    host.reopen(hung_up=lambda: not sim.connected)
    host.wait_start()
    assert sim.last_line == 0
    host.read_until(lambda line: line.startswith("echo: Free"))
    assert host.command(1, "G1 X2") == ["ok"]


def test_idle_printer_says_wait_with_no_timeouts():
    with SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0, no_timeouts_s=0.1)) as sim:
        link = Host(sim.start())
        link.wait_start()
        assert link.read_until(lambda line: line == "wait", timeout=2.0)[-1] == "wait"
        link.close()


def test_command_cut_short_by_a_reset_is_not_logged():
    with SimulatedPrinter(SimulatorConfig(time_scale=1.0, baud=0)) as sim:
        link = Host(sim.start())
        link.wait_start()
        link.read_until(lambda line: line.startswith("echo: Free"))
        link.command(1, "M104 S200")
        link.send(2, "M109 S200")
        link.read_until(lambda line: "W:" in line)
        sim.reset()
        link.wait_start()
        assert sim.executed == ["M104 S200"]
        assert sim.last_line == 0
        link.close()
