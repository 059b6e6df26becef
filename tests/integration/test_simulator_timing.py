"""The simulated printer's clock: move times, dwell, heaters, keepalive, wire speed, buffers."""

from __future__ import annotations

import math
import time

import pytest
from support.simhost import Host
from support.waiting import wait_until

from drivers.link.protocol import frame
from drivers.sim.heater import BED, HOTEND, Heater
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig


def _open(sim: SimulatedPrinter) -> Host:
    link = Host(sim.start())
    link.wait_start()
    link.read_until(lambda line: line.startswith("echo: Free"))
    return link


def _run(commands: list[str], **config) -> tuple[SimulatedPrinter, list[str]]:
    settings = {"time_scale": 0.0, "baud": 0, **config}
    sim = SimulatedPrinter(SimulatorConfig(**settings))
    link = _open(sim)
    received: list[str] = []
    try:
        for number, command in enumerate(commands, start=1):
            received += link.command(number, command, timeout=10.0)
    finally:
        link.close()
        sim.stop()
    return sim, received


def test_move_time_is_length_over_feedrate():
    sim, _ = _run([
        "G1 X30 F600",          # 30 mm at 10 mm/s: 3 s
        "G1 Y40",               # from (30, 0) to (30, 40), F modal: 4 s
        "G91",
        "G1 X-30 Y-40 F3000",   # 50 mm at 50 mm/s: 1 s
        "G1 Z2 F600",           # Z limited to 5 mm/s: 0.4 s
        "M83",
        "G1 E5 F300",           # extrude only: 5 mm at 5 mm/s: 1 s
        "G90",
        "G92 X100",
        "G1 X100 F600",         # no movement: no time
        "M220 S200",
        "G1 X110 F600",         # 10 mm at 2 x 10 mm/s: 0.5 s
    ])
    stats = sim.stats()
    assert stats.motion_s == pytest.approx(3 + 4 + 1 + 0.4 + 1 + 0.5)
    assert stats.moves == 6
    assert stats.distance_mm == pytest.approx(30 + 40 + 50 + 2 + 5 + 10)


def test_dwell_and_homing_take_simulated_time():
    sim, received = _run(["G1 X50 Y20 Z10 F6000", "G4 P1500", "G4 S2", "G28"])
    stats = sim.stats()
    assert stats.dwell_s == pytest.approx(3.5)
    assert stats.home_s == pytest.approx(3.0 + 50 / 50.0 + 10 / 4.0)
    # a command running for two keepalive intervals reports busy twice
    assert received.count("echo:busy: processing") >= 3


def test_wall_time_follows_time_scale():
    scale = 0.05
    sim = SimulatedPrinter(SimulatorConfig(time_scale=scale, baud=0))
    link = _open(sim)
    try:
        started = time.monotonic()
        link.command(1, "G1 X20 F600")   # 2 s simulated
        link.command(2, "G1 X0 F1200")   # 1 s simulated
        link.command(3, "M400")          # waits for the planner to empty
        elapsed = time.monotonic() - started
    finally:
        link.close()
        sim.stop()
    assert sim.stats().motion_s == pytest.approx(3.0)
    assert elapsed >= 3.0 * scale * 0.95  # the moves were played out, not skipped


def test_planner_holds_the_ok_while_full():
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.02, baud=0, planner_blocks=2))
    link = _open(sim)
    try:
        started = time.monotonic()
        for number in range(1, 4):  # 3 moves of 1 s into a 2-block planner
            link.command(number, f"G1 X{number * 10} F600")
        elapsed = time.monotonic() - started
    finally:
        link.close()
        sim.stop()
    assert elapsed >= 1.0 * 0.02 * 0.95  # the third ok waited for the first block


def test_heater_model_reaches_target_in_minutes():
    hotend = Heater(HOTEND, 20.0)
    hotend.set_target(210.0, 0.0)
    assert hotend.temperature(0.0) == pytest.approx(20.0)
    assert 100.0 < hotend.temperature(15.0) < 150.0
    reach = next(t for t in range(600) if hotend.settled(float(t), heating_only=False))
    assert 60 <= reach <= 180
    bed = Heater(BED, 20.0)
    bed.set_target(60.0, 0.0)
    reach = next(t for t in range(600) if bed.settled(float(t), heating_only=False))
    assert 60 <= reach <= 180
    hotend.set_target(0.0, 300.0)
    assert hotend.temperature(900.0) < hotend.temperature(400.0) < 210.0


def test_m109_waits_with_temperature_lines_and_busy():
    _, received = _run(["M104 S210", "M140 S60", "M190 S60", "M109 S210", "M105"])
    waits = [line for line in received if " W:" in line]
    busy = received.count("echo:busy: processing")
    # one temperature line per simulated second, busy every two
    assert 120 <= len(waits) <= 360
    assert busy >= len(waits) // 2 - 4
    assert waits[-1].endswith(" W:0")
    final = received[-1]
    t = float(final.split("T:")[1].split()[0])
    b = float(final.split("B:")[1].split()[0])
    assert math.isclose(t, 210.0, abs_tol=1.0)
    assert math.isclose(b, 60.0, abs_tol=1.0)


def test_autoreport_sends_temperatures_without_being_asked():
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0))
    link = _open(sim)
    try:
        link.command(1, "M155 S0.2")
        lines = link.read_until(lambda line: line.startswith(" T:"), timeout=2.0)
        assert lines[-1].startswith(" T:")
        assert " B@:" in lines[-1]
        link.command(2, "M155 S0")
        link.readline(0.3)
        assert link.readline(0.5) is None
    finally:
        link.close()
        sim.stop()


def test_wire_speed_limits_replies():
    baud = 19200
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=baud))
    link = _open(sim)
    try:
        started = time.monotonic()
        lines = link.command(1, "M115")
        elapsed = time.monotonic() - started
    finally:
        link.close()
        sim.stop()
    size = sum(len(line) + 1 for line in lines)
    assert size > 500
    assert elapsed >= 0.9 * (size - 64) / (baud / 10)  # minus one burst


def test_wire_speed_limits_what_the_printer_reads():
    baud = 19200
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=baud))
    link = _open(sim)
    lines = [f"G1 X{n % 10}.123 Y{n % 7}.456 E{n}.78901 F1200 ; padding".encode() + b"\n"
             for n in range(12)]
    try:
        started = time.monotonic()
        for line in lines:  # one at a time: the firmware is never short of buffer
            link.write(line)
            assert link.readline(5.0) == "ok"
        elapsed = time.monotonic() - started
    finally:
        link.close()
        sim.stop()
    size = sum(len(line) for line in lines)
    assert elapsed >= 0.9 * (size - 64) / (baud / 10)
    assert len(sim.executed) == len(lines)


def test_quick_stop_empties_the_planner():
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0, advanced_ok=True))
    link = _open(sim)
    try:
        assert link.command(1, "G1 X100 F600") == ["ok N1 P15 B3"]
        assert link.command(2, "G1 X0") == ["ok N2 P14 B3"]
        link.command(3, "M410")  # acted on by the emergency parser
        assert link.command(4, "G1 X50") == ["ok N4 P15 B3"]
    finally:
        link.close()
        sim.stop()


def test_receive_buffer_overflow_loses_bytes():
    sim = SimulatedPrinter(SimulatorConfig(time_scale=1.0, baud=0, rx_buffer=128))
    link = _open(sim)
    commands = [f"G1 X{n} Y{n} F3000" for n in range(2, 22)]
    try:
        link.send(1, "G4 P400")  # the firmware is busy for 0.4 s and reads nothing
        wait_until(lambda: sim.last_line == 1, 2.0, "the G4 taken (the firmware then dwells)")
        burst = b"".join(frame(n, c) for n, c in enumerate(commands, start=2))
        link.write(burst)
        assert link.readline(2.0) == "ok"  # G4
        kept = burst[:128]
        whole = kept.count(b"\n")
        for _ in range(whole):
            assert link.readline(2.0) == "ok"
        link.send(22, "G1 X0")  # completes the torn line: a checksum error
        lines = link.read_until(lambda line: line.startswith("ok"), timeout=2.0)
    finally:
        link.close()
        sim.stop()
    assert sim.stats().rx_overflow_bytes == len(burst) - 128
    assert sim.executed == ["G4 P400", *commands[:whole]]
    assert lines == [
        f"Error:checksum mismatch, Last Line: {whole + 1}",
        f"Resend: {whole + 2}",
        "ok",
    ]
