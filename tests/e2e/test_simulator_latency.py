"""The simulated link's latency and wire pacing: lower bounds on round trips, same results."""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
import time

import pytest
import serial
from support.simhost import Host

from drivers.link.protocol import frame
from drivers.link.streamer import Streamer, StreamerConfig
from drivers.link.transport import open_transport
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig


def _open(sim: SimulatedPrinter) -> Host:
    link = Host(sim.start())
    link.wait_start()
    link.read_until(lambda line: line.startswith("echo: Free"))
    return link


def _moves(n: int) -> list[str]:
    return [f"G1 X{100 + 30 * math.cos(0.05 * i):.3f} Y{100 + 30 * math.sin(0.05 * i):.3f} "
            f"E{0.01 * (i % 13):.3f} F6000" for i in range(n)]


def _round_trip(sim: SimulatedPrinter, command: str) -> tuple[float, int, list[str]]:
    """Wall seconds from writing ``N1 command`` to its ``ok``; bytes both ways; replies."""
    link = _open(sim)
    try:
        data = frame(1, command)
        started = time.monotonic()
        link.write(data)
        replies = link.read_until(lambda line: line.startswith("ok"), timeout=10.0)
        elapsed = time.monotonic() - started
    finally:
        link.close()
    return elapsed, len(data) + sum(len(line) + 1 for line in replies), replies


@pytest.mark.parametrize(("latency_s", "baud"), [(0.02, 115200), (0.05, 0), (0.01, 9600)])
def test_m105_round_trip_takes_twice_the_latency_plus_wire_time(latency_s, baud):
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=baud, latency_s=latency_s))
    try:
        elapsed, size, replies = _round_trip(sim, "M105")
    finally:
        sim.stop()
    assert replies[-1].startswith("ok T:")
    wire = size / (baud / 10) if baud else 0.0
    assert elapsed >= 2 * latency_s + wire


def test_bytes_arrive_no_earlier_than_their_wire_time_after_an_idle_gap():
    # the line is idle (the banner long gone), then M115 and its long reply cross a slow
    # wire: no byte of either may arrive early, not even a first burst
    baud = 19200
    sim = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=baud))
    try:
        elapsed, size, replies = _round_trip(sim, "M115")
    finally:
        sim.stop()
    assert size > 500
    assert replies[-1] == "ok"
    assert elapsed >= size / (baud / 10)


def test_latency_is_range_checked():
    with pytest.raises(ValueError, match="latency_s"):
        SimulatorConfig(latency_s=-0.001)
    with pytest.raises(ValueError, match="latency_s"):
        SimulatorConfig(latency_s=2.0)
    assert SimulatorConfig().latency_s == 0.0


def _stream(config: SimulatorConfig, lines: list[str]) -> list[str]:
    """Stream ``lines`` with the windowed streamer; the printer's executed log."""

    async def run(path: str) -> None:
        settings = StreamerConfig(temperature_interval_s=0)
        async with Streamer(await open_transport(path, config.baud or 250000), settings) as link:
            await link.connect()
            for line in lines:
                await link.send(line)
            await link.drain()

    sim = SimulatedPrinter(config)
    try:
        asyncio.run(run(sim.start()))
        stats = sim.stats()
    finally:
        sim.stop()
    assert stats.errors == 0
    assert stats.rx_overflow_bytes == 0
    return sim.executed


def test_a_clean_run_executes_the_same_lines_with_latency(tmp_path):
    moves = _moves(150)
    logs = {}
    for latency_s in (0.0, 0.003):
        log = tmp_path / f"executed-{latency_s}.log"
        config = SimulatorConfig(time_scale=0.0, baud=250000, latency_s=latency_s,
                                 boot_delay_s=0.0, log_path=str(log))
        executed = _stream(config, moves)
        assert [c for c in executed if c.startswith("G1")] == moves
        assert log.read_text().splitlines() == executed
        logs[latency_s] = executed
    assert logs[0.0] == logs[0.003]


def test_hostd_simulate_latency_option():
    latency_ms = 30.0
    proc = subprocess.Popen(
        [sys.executable, "-m", "hostd.app.cli", "simulate", "--time-scale", "0", "--baud", "0",
         "--latency-ms", str(latency_ms)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        with serial.Serial(path, 250000, timeout=3) as port:
            assert port.readline() == b"start\n"
            port.readline()
            port.readline()
            started = time.monotonic()
            port.write(frame(1, "M105"))
            reply = port.readline().decode()
            elapsed = time.monotonic() - started
        assert reply.startswith("ok T:"), reply
        assert elapsed >= 2 * latency_ms / 1000.0
        proc.terminate()
        assert proc.wait(timeout=5) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
