"""Marlin's planner in the simulator: trapezoids, corners, arcs, underruns, the wire feed model."""

from __future__ import annotations

import itertools
import math

import pytest
from support.simhost import Host

from drivers.sim.feed import simulate_feed
from drivers.sim.planner import MarlinPlanner, PlannerSettings, arc_segments, move_block
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig

SETTINGS = PlannerSettings()


def _feed(
    planner: MarlinPlanner, t: float, moves: list[tuple[float, float]], speed: float
) -> float:
    """Queue XY moves at ``t`` (waiting for slots as the firmware does); returns the time."""
    for dx, dy in moves:
        planned = move_block((dx, dy, 0.0, 0.0), speed, planner.settings, planner.previous)
        assert planned is not None
        block, planner.previous = planned
        t = planner.add_block(t, block)
    return t


def test_a_straight_line_of_short_moves_runs_at_speed() -> None:
    planner = MarlinPlanner()
    t = _feed(planner, 0.0, [(1.0, 0.0)] * 200, 100.0)
    end = planner.idle_at(t)
    ideal = 200.0 / 100.0
    ramps = 2 * 100.0 / SETTINGS.acceleration  # accelerate once, brake once
    # three blocks queued at once start the motion without the first-move delay
    assert end == pytest.approx(ideal + ramps / 2, rel=0.02)
    assert planner.underruns == 0
    assert planner.stalls == 0


def test_sharp_corners_cost_time_and_gentle_ones_do_not() -> None:
    square = [(10.0, 0.0), (0.0, 10.0), (-10.0, 0.0), (0.0, -10.0)] * 5
    n = 80
    polygon = [
        (math.cos(2 * math.pi * (k + 1) / n) - math.cos(2 * math.pi * k / n),
         math.sin(2 * math.pi * (k + 1) / n) - math.sin(2 * math.pi * k / n))
        for k in range(n)
    ]
    polygon = [(20 * x, 20 * y) for x, y in polygon] * 2  # radius 20 mm, 1.57 mm chords
    times = []
    for path in (square, polygon):
        planner = MarlinPlanner()
        length = sum(math.hypot(*m) for m in path)
        end = planner.idle_at(_feed(planner, 0.0, path, 100.0)) - SETTINGS.first_move_delay_s
        times.append(end / (length / 100.0))
    assert times[0] > 1.15  # slows to 10 mm/s at every right angle
    assert times[1] < 1.1  # rolls through the polygon's corners


def test_a_well_fed_planner_never_underruns() -> None:
    planner = MarlinPlanner()
    t = 0.0
    for _ in range(100):  # each move queued as soon as a slot is free
        t = _feed(planner, t, [(5.0, 0.0), (0.0, 5.0)], 100.0)
    planner.idle_at(t)
    assert planner.underruns == 0
    assert planner.stalls == 0
    assert planner.starved_s == 0.0


def test_a_starved_planner_counts_underruns_and_starved_time() -> None:
    planner = MarlinPlanner()
    t = 0.0
    for k in range(10):  # a 0.05 s move every 0.5 s: empty most of the time
        _feed(planner, t, [(5.0 if k % 2 else -5.0, 0.0)], 100.0)
        t += 0.5
    planner.idle_at(t)
    assert planner.underruns == 9
    assert planner.stalls == 9
    assert 9 * 0.3 < planner.starved_s < 9 * 0.5
    report = planner.report(t)
    assert report.underruns == 9
    assert report.longest_ms > 300
    assert planner.report(t).underruns == 0  # per report, as Marlin's M576


def test_idle_after_a_long_command_is_not_an_underrun() -> None:
    planner = MarlinPlanner()
    t = _feed(planner, 0.0, [(10.0, 0.0)], 50.0)
    t = planner.idle_at(t) + 30.0  # G4 S30 (or homing, heating) after the move
    _feed(planner, t, [(-10.0, 0.0)], 50.0)
    planner.idle_at(t)
    assert planner.underruns == 0
    assert planner.starved_s == 0.0


def test_arcs_are_cut_as_marlin_cuts_them() -> None:
    # a quarter turn of radius 10 mm: 15.7 mm, 1 mm segments at most, 72 a full turn
    points = arc_segments((10.0, 0.0), (0.0, 10.0), (0.0, 0.0), False, SETTINGS)
    assert len(points) == 18
    assert points[-1] == (0.0, 10.0)
    for x, y in points:
        assert math.hypot(x, y) == pytest.approx(10.0)
    assert all(y2 > y1 for (_, y1), (_, y2) in itertools.pairwise(points))
    # clockwise the other way round: three quarters of a turn
    assert len(arc_segments((10.0, 0.0), (0.0, 10.0), (0.0, 0.0), True, SETTINGS)) == 54
    # same start and end: a full circle
    assert len(arc_segments((10.0, 0.0), (10.0, 0.0), (0.0, 0.0), True, SETTINGS)) == 72


def _circle_lines(segments: int, laps: int, feed_mm_min: int) -> list[str]:
    points = [
        (100 + 10 * math.cos(a), 100 + 10 * math.sin(a))
        for a in (2 * math.pi * k / segments for k in range(segments + 1))
    ]
    lines = ["G28", "G90", "M83", f"G0 F9000 X{points[0][0]:.3f} Y{points[0][1]:.3f} Z0.2"]
    for _ in range(laps):
        lines.append(f"G1 F{feed_mm_min} X{points[1][0]:.3f} Y{points[1][1]:.3f} E0.01")
        lines += [f"G1 X{x:.3f} Y{y:.3f} E0.01" for x, y in points[2:]]
    return lines


def test_feed_over_a_slow_wire_starves_and_arcs_do_not() -> None:
    dense = _circle_lines(400, 5, 9000)  # 0.16 mm segments at 150 mm/s: 950 lines/s
    slow = simulate_feed(dense, 115200, send_and_wait=True)
    fed = simulate_feed(dense, 0)
    assert slow.stalls > 100
    assert slow.print_s > 1.3 * fed.print_s
    assert fed.stalls == 0
    assert fed.underruns == 0
    arcs = ["G28", "G90", "M83", "G0 F9000 X110 Y100 Z0.2"]
    arcs += ["G3 F9000 X110 Y100 I-10 J0 E4"] * 5
    result = simulate_feed(arcs, 115200, send_and_wait=True)
    assert result.arcs == 5
    assert result.blocks == 1 + 5 * 72
    assert result.underruns == 0
    assert result.stalls == 0
    # the 0.16 mm chords limit the look-ahead even on an endless wire: 16 blocks are
    # 2.5 mm, less than the 3.75 mm needed to brake from 150 mm/s; the arcs' 0.87 mm are not
    assert result.print_s < 0.9 * fed.print_s


def _open(sim: SimulatedPrinter) -> Host:
    host = Host(sim.start())
    host.wait_start()
    host.read_until(lambda line: line.startswith("echo: Free"))
    return host


def test_simulator_executes_and_logs_arcs() -> None:
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0))
    host = _open(sim)
    try:
        host.command(1, "G1 X20 Y10 F600")
        host.command(2, "M83")
        host.command(3, "G2 X20 Y10 I-10 J0 E3 F1200")  # a full circle, radius 10
        host.command(4, "G3 X10 Y0 I-10 J0 F1200")  # a quarter turn back
        lines = host.command(5, "M114")
        host.command(6, "M400")
    finally:
        host.close()
        sim.stop()
    assert "G2 X20 Y10 I-10 J0 E3 F1200" in sim.executed
    assert "G3 X10 Y0 I-10 J0 F1200" in sim.executed
    position = next(line for line in lines if line.startswith("X:"))
    assert position.startswith("X:10.00 Y:0.00")
    stats = sim.stats()
    assert stats.arcs == 2
    assert stats.arc_segments == 72 + 54
    arc_s = (2 * math.pi * 10 + 1.5 * math.pi * 10) / 20.0
    assert stats.motion_s == pytest.approx(math.hypot(20, 10) / 10.0 + arc_s, rel=1e-3)
    assert stats.planned_s > stats.motion_s  # acceleration and the chords' corners


def test_simulator_counts_an_underrun_when_starved_and_none_when_fed() -> None:
    # 0.1 wall s per fed move: the host answers far sooner, even on a loaded machine
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.05, baud=0))
    host = _open(sim)
    try:
        n = 1
        for x in (10, 0, 10):  # each move once the planner has run empty (M576 P16)
            host.command(n, f"G1 X{x} F6000")
            n += 1
            while True:
                report = next(line for line in host.command(n, "M576") if line.startswith("M576"))
                n += 1
                if report.startswith("M576 P16"):
                    break
        underruns = sim.stats().underruns
        report = next(line for line in host.command(n, "M576") if line.startswith("M576"))
        n += 1
        host.command(n, "M400")
        n += 1
        for x in range(8):  # 8 moves of 2 s sent back to back
            host.command(n, f"G1 X{20 * (x % 2)} F600")
            n += 1
        host.command(n, "M400")
    finally:
        host.close()
        sim.stop()
    assert underruns == 2
    assert report.startswith("M576 P16 B")
    assert sim.stats().underruns == 2  # none more while fed
    assert sim.stats().starved_s > 0.0
