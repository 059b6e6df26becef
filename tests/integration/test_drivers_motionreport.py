"""The printer's motion settings read from its M503 answer: Marlin's forms, other firmware."""

from __future__ import annotations

import asyncio

import pytest
from support.streaming import INTERNAL, scripted, stream_scripted

from drivers.link.config import StreamerConfig
from drivers.link.motion import parse_motion_report
from drivers.link.streamer import Streamer
from drivers.link.transport import open_transport
from drivers.sim.config import SimulatorConfig
from drivers.sim.printer import SimulatedPrinter
from drivers.sim.report import report_lines

# Marlin 2.1 (M503): every line after echo:, headings as comments
MARLIN_21 = """\
echo:; Linear Units:
echo:  G21 ; (mm)
echo:; Temperature Units:
echo:  M149 C ; Units in Celsius
echo:; Filament settings (Disabled):
echo:  M200 S0 D1.75
echo:; Steps per unit:
echo:  M92 X80.00 Y80.00 Z400.00 E93.00
echo:; Max feedrates (units/s):
echo:  M203 X500.00 Y500.00 Z5.00 E25.00
echo:; Max Acceleration (units/s2):
echo:  M201 X500.00 Y500.00 Z100.00 E5000.00
echo:; Acceleration (units/s2) (P<print-accel> R<retract-accel> T<travel-accel>):
echo:  M204 P500.00 R500.00 T1000.00
echo:; Advanced (B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> J<junc_dev>):
echo:  M205 B20000.00 S0.00 T0.00 J0.08
echo:; Home offset:
echo:  M206 X0.00 Y0.00 Z0.00
echo:; Hotend PID:
echo:  M301 P21.73 I1.54 D76.55
ok"""

# Marlin 1.1.9 with classic jerk, headings without ';', a temperature report in between
MARLIN_119 = """\
echo:Steps per unit:
echo:  M92 X80.00 Y80.00 Z400.00 E93.00
echo:Maximum feedrates (units/s):
echo:  M203 X500.00 Y500.00 Z5.00 E25.00
echo:Maximum Acceleration (units/s2):
echo:  M201 X3000 Y2000 Z100 E5000
 T:205.00 /205.00 B:60.00 /60.00 @:31 B@:0
echo:Acceleration (units/s2): P<print_accel> R<retract_accel> T<travel_accel>
echo:  M204 P2500.00 R1000.00 T3000.00
echo:Advanced: B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> X<max_x_jerk>
echo:  M205 B20000 S0.00 T0.00 X10.00 Y10.00 Z0.30 E5.00
ok"""

# Prusa firmware (Marlin 1.0 lineage): M204 S (printing and travel) T (retracts)
PRUSA_OLD = """\
echo:Maximum feedrates (mm/s):
echo:  M203 X200.00 Y200.00 Z12.00 E120.00
echo:Maximum Acceleration (mm/s2):
echo:  M201 X1000 Y1000 Z200 E5000
echo:Acceleration: S=acceleration, T=retract acceleration
echo:  M204 S1250.00 T1250.00
ok"""

# M503 S0 (for replay): the commands alone, no echo:, no headings; two extruders
MARLIN_S0 = """\
G21
M92 X80.00 Y80.00 Z400.00 T0 E93.00
M203 X300.00 Y300.00 Z5.00 T0 E25.00
M203 T1 E40.00
M201 X4000.00 Y4000.00 Z100.00 T0 E10000.00
M201 T1 E2000.00
M204 P4000.00 R3000.00 T5000.00
ok"""


def parse(text: str):
    return parse_motion_report(text.splitlines())


def test_marlin_2_1_report_with_junction_deviation() -> None:
    motion = parse(MARLIN_21)
    assert motion.max_acceleration == {"X": 500.0, "Y": 500.0, "Z": 100.0, "E": 5000.0}
    assert motion.max_feedrate == {"X": 500.0, "Y": 500.0, "Z": 5.0, "E": 25.0}
    assert (motion.print_acceleration, motion.retract_acceleration,
            motion.travel_acceleration) == (500.0, 500.0, 1000.0)
    assert motion.junction_deviation == pytest.approx(0.08)
    assert motion.jerk == {}
    assert motion.printing_acceleration() == 500.0
    assert motion.travelling_acceleration() == 500.0  # capped by M201 X and Y
    assert "travel acceleration 1000" in motion.describe()


def test_marlin_1_1_report_with_jerk_and_a_temperature_line_between() -> None:
    motion = parse(MARLIN_119)
    assert motion.print_acceleration == 2500.0
    assert motion.printing_acceleration() == 2000.0  # M201 Y is the lower cap
    assert motion.travelling_acceleration() == 2000.0
    assert motion.junction_deviation is None
    assert motion.jerk == {"X": 10.0, "Y": 10.0, "Z": 0.3, "E": 5.0}


def test_the_older_m204_s_form_means_printing_and_travel_with_t_for_retracts() -> None:
    motion = parse(PRUSA_OLD)
    assert (motion.print_acceleration, motion.travel_acceleration,
            motion.retract_acceleration) == (1250.0, 1250.0, 1250.0)
    assert motion.printing_acceleration() == 1000.0


def test_a_report_for_replay_with_two_extruders_keeps_the_first_extruder_s() -> None:
    motion = parse(MARLIN_S0)
    assert motion.max_acceleration == {"X": 4000.0, "Y": 4000.0, "Z": 100.0, "E": 10000.0}
    assert motion.max_feedrate["E"] == 25.0
    assert motion.printing_acceleration() == 4000.0
    assert motion.travelling_acceleration() == 4000.0


def test_missing_fields_stay_unknown_and_other_firmware_reports_nothing() -> None:
    partial = parse("echo:  M201 X800 Y900\nok")
    assert partial.print_acceleration is None
    assert partial.printing_acceleration() == 800.0  # the axis limit alone
    only = parse("echo:  M204 P1500\nok")
    assert only.printing_acceleration() == 1500.0
    assert only.max_acceleration == {}
    for text in ('// Unknown command:"M503"\nok', 'echo:Unknown command: "M503"\nok', "ok", "",
                 "echo:  M204 Pnan R-5 T\nM2010 X5\nM20 X1\nok"):
        motion = parse(text)
        assert not motion.reported, text
        assert motion.printing_acceleration() is None
        assert motion.describe() == "nothing reported"


def test_the_simulated_printer_reports_its_planner_settings_and_the_link_reads_them() -> None:
    config = SimulatorConfig(time_scale=0.0, baud=0, acceleration=1700.0)
    lines = report_lines(config.planner())
    assert parse("\n".join(lines)).printing_acceleration() == 1700.0

    async def connect(read: bool) -> tuple[Streamer, list[str]]:
        with SimulatedPrinter(config) as sim:
            link_config = StreamerConfig(read_motion=read)
            async with Streamer(await open_transport(sim.start(), 250000), link_config) as link:
                await link.connect()
                await link.drain()
            return link, list(sim.executed)

    link, executed = asyncio.run(connect(read=False))
    assert "M503" not in executed
    assert not link.motion.reported
    link, executed = asyncio.run(connect(read=True))
    assert "M503" in executed
    assert link.motion.printing_acceleration() == 1700.0
    assert link.motion.junction_deviation == pytest.approx(0.013)
    assert link.motion.max_feedrate == {"X": 300.0, "Y": 300.0, "Z": 5.0, "E": 25.0}


def test_a_printer_that_never_answers_m503_still_connects_with_nothing_learned() -> None:
    def silent(number: int | None, command: str) -> list[str] | None:
        return [] if command == "M503" else None  # dropped: no reply, no ok

    with scripted(silent) as printer:
        link = asyncio.run(stream_scripted(printer, ["G1 X1 F600", "G1 X2"]))
        executed = [c for c in printer.executed if c.split()[0] not in INTERNAL]
    assert not link.motion.reported
    assert executed == ["G1 X1 F600", "G1 X2"]
