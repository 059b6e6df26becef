"""Fault injection of the simulated printer: each kind fires at its rate, seeded, and a
careful host still gets every line executed exactly once."""

from __future__ import annotations

import math
import os
import re

import pytest
from support.simhost import Host, PortGone, stream

from drivers.sim.faults import FaultInjector
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig
from slicer.options import SettingError

P = 0.05
LINES = 400
COMMANDS = [f"G1 X{i % 90} Y{(i * 7) % 90} E{i * 0.01:.2f} F6000" for i in range(LINES)]
KNOWN = re.compile(
    r"^(ok( N\d+ P\d+ B\d+)?|start|Resend: \d+|Error:.*|echo:.*|FIRMWARE_NAME:.*|Cap:.*"
    r"|ok T:.*| T:.*)$"
)


def _within_binomial(fired: int, chances: int, p: float) -> bool:
    sigma = math.sqrt(chances * p * (1 - p))
    return abs(fired - chances * p) <= 4 * sigma + 1


def _run(tmp_path, **faults) -> tuple[SimulatedPrinter, Host]:
    config = SimulatorConfig(
        time_scale=0.0, baud=0, seed=7, link_path=str(tmp_path / "printer"),
        reconnect_delay_s=0.05, **faults,
    )
    sim = SimulatedPrinter(config)
    sim.start()
    link = Host(config.link_path)
    link.wait_start()
    stream(link, COMMANDS, ok_timeout=0.25)
    link.close()
    sim.stop()
    return sim, link


def _executed(sim: SimulatedPrinter) -> list[str]:
    return [c for c in sim.executed if not c.startswith("M110")]


@pytest.mark.parametrize(
    "kind", ["corrupt_rx", "corrupt_tx", "drop_ok", "resend", "busy", "reset", "disconnect"]
)
def test_each_fault_fires_at_its_rate_and_lines_run_once(tmp_path, kind):
    sim, link = _run(tmp_path, **{f"p_{kind}": P})
    stats = sim.stats()
    fired, chances = stats.faults.get(kind, 0), stats.fault_chances.get(kind, 0)
    assert chances >= LINES
    assert fired > 0, (fired, chances)
    assert _within_binomial(fired, chances, P), (fired, chances)
    assert set(stats.faults) == {kind}
    assert _executed(sim) == COMMANDS
    received = link.received
    if kind == "corrupt_rx":
        assert stats.errors >= fired * 0.8
    elif kind == "corrupt_tx":
        assert sum(not KNOWN.match(line) for line in received) >= fired * 0.5
    elif kind == "drop_ok":  # the host re-sends after a lost ok: a duplicate, rejected
        assert stats.errors == stats.line_number_errors >= fired * 0.8
    elif kind == "resend":
        spurious = [
            i for i, line in enumerate(received)
            if line.startswith("Resend") and not received[i - 1].startswith("Error")
        ]
        assert len(spurious) == fired
    elif kind == "busy":
        assert received.count("echo:busy: processing") >= fired
    elif kind in ("reset", "disconnect"):
        assert received.count("start") == fired + 1
        assert stats.resets == fired + 1


def test_all_faults_combined(tmp_path):
    kinds = ("corrupt_rx", "corrupt_tx", "drop_ok", "resend", "busy", "reset")
    sim, _ = _run(tmp_path, **{f"p_{kind}": 0.01 for kind in kinds})
    assert _executed(sim) == COMMANDS


def test_disconnect_makes_the_port_vanish(tmp_path):
    link_path = str(tmp_path / "printer")
    config = SimulatorConfig(time_scale=0.0, baud=0, link_path=link_path, reconnect_delay_s=0.3)
    with SimulatedPrinter(config) as sim:
        link = Host(link_path)
        link.wait_start()
        sim.disconnect()
        with pytest.raises(PortGone):
            for _ in range(50):
                link.readline(0.05)
        assert not os.path.lexists(link_path)  # gone until the printer comes back
        link.reopen(timeout=3.0)
        link.wait_start()
        assert os.path.realpath(link_path) == sim.path
        link.close()


def test_faults_are_reproducible_for_a_seed():
    def draws(seed: int, p_other: float) -> list[bool]:
        faults = FaultInjector(SimulatorConfig(seed=seed, p_drop_ok=0.3, p_busy=p_other))
        out = []
        for _ in range(200):
            out.append(faults.fires("drop_ok"))
            faults.fires("busy")
        return out

    assert draws(1, 0.0) == draws(1, 0.9)  # another kind never shifts the draws
    assert draws(1, 0.5) != draws(2, 0.5)
    assert 30 <= sum(draws(3, 0.0)) <= 90


def test_config_rejects_bad_values():
    # the project's one settings error, naming the key, as the link's settings raise it
    with pytest.raises(SettingError, match="p_drop_ok") as caught:
        SimulatorConfig(p_drop_ok=1.5)
    assert caught.value.key == "p_drop_ok"
    assert "probability" in caught.value.reason
    with pytest.raises(SettingError, match="bufsize") as caught:
        SimulatorConfig(bufsize=0)
    assert caught.value.key == "bufsize"


def test_unplugging_mid_command_cuts_it_short(tmp_path):
    link_path = str(tmp_path / "printer")
    config = SimulatorConfig(time_scale=1.0, baud=0, link_path=link_path, reconnect_delay_s=0.1)
    with SimulatedPrinter(config) as sim:
        link = Host(link_path)
        link.wait_start()
        link.read_until(lambda line: line.startswith("echo: Free"))
        link.command(1, "G1 X5")
        link.send(2, "M109 S200")
        link.read_until(lambda line: "W:" in line)
        sim.disconnect()
        with pytest.raises(PortGone):
            for _ in range(100):
                link.readline(0.05)
        link.reopen(timeout=3.0)
        link.wait_start()
        assert sim.executed == ["G1 X5"]  # the heating wait never completed
        assert sim.last_line == 0
        link.close()
