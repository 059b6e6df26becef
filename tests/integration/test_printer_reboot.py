"""A printer that rebooted while no host had the port open is told from one that kept its power
by the line numbering it still counts (a probe before the handshake's M110)."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

from support.linkrun import arc_job as job
from support.streaming import FAST, job_lines, sim_config
from support.waiting import wait_until

from drivers.link.numbering import NumberingProbe
from drivers.link.responses import parse_response
from drivers.link.streamer import Streamer
from drivers.link.transport import open_transport
from drivers.sim.printer import SimulatedPrinter
from hostd.config import config_from_mapping
from hostd.printing.printer import printer_link

QUIET = dataclasses.replace(FAST, temperature_interval_s=0.0)  # no M105 polls of its own


def answered(lines: list[str], ok_after_resend: bool = True) -> tuple[NumberingProbe, list[str]]:
    """The probe after ``lines``, and the lines it left to the link."""
    probe = NumberingProbe(ok_after_resend)
    left = [line for line in lines if not probe.take(parse_response(line))]
    return probe, left


def test_the_probe_reads_every_form_of_answer() -> None:
    probe, left = answered(["ok T:20.0 /0.0 B:20.0 /0.0"])
    assert (probe.kept, probe.last_line, probe.done, left) == (False, 0, True, [])
    # a plain ok is a line the last host left in the queue: not the probe's
    probe, left = answered(["ok", "echo:busy: processing", "ok T:20.0 /0.0"])
    assert (probe.kept, probe.done, left) == (False, True, ["ok", "echo:busy: processing"])
    probe, left = answered(["T:20.0 /0.0 B:20.0 /0.0", "ok"])  # the report on its own line
    assert (probe.kept, probe.done, left) == (False, True, ["T:20.0 /0.0 B:20.0 /0.0"])
    refusal = ["Error:Line Number is not Last Line Number+1, Last Line: 812", "Resend: 813"]
    probe, left = answered([*refusal, "ok", "ok"])
    assert (probe.kept, probe.last_line, probe.done, left) == (True, 812, True, ["ok"])
    probe, left = answered([*refusal, "ok"], ok_after_resend=False)  # a build without it
    assert (probe.kept, probe.done, left) == (True, True, ["ok"])
    # noise broke the probe's checksum on a board that booted: the Last Line still tells
    probe, _ = answered(["Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"])
    assert (probe.kept, probe.done) == (False, True)
    probe, left = answered(["start"])  # it booted while the probe was out
    assert (probe.kept, probe.done, left) == (False, True, ["start"])


async def _session(sim: SimulatedPrinter, lines: list[str]) -> Streamer:
    """Connect with the probe, stream ``lines``, drain, close (the printer keeps power)."""
    async with Streamer(await open_transport(sim.path, 250000), QUIET) as link:
        await link.connect(probe_numbering=True)
        for line in lines:
            await link.send(line)
        await link.drain()
    return link


def test_a_reboot_with_no_host_on_the_port_is_told_from_kept_power() -> None:
    lines = job(60)
    starts: list[int] = []  # where each session's commands begin in the executed log
    with SimulatedPrinter(sim_config(reset_on_open=False)) as sim:
        starts.append(len(sim.executed))
        first = asyncio.run(_session(sim, lines[:20]))
        assert first.numbering_kept is False  # it booted when switched on
        counted = sim.last_line
        assert counted > 20
        starts.append(len(sim.executed))
        second = asyncio.run(_session(sim, lines[20:40]))
        assert (second.numbering_kept, second.numbering_last_line) == (True, counted)
        sim.reset()  # the reset button, nobody on the port: its banner goes unread
        wait_until(lambda: sim.last_line == 0, 5, "the printer to reboot")
        starts.append(len(sim.executed))
        third = asyncio.run(_session(sim, lines[40:]))
        assert third.numbering_kept is False
        executed = list(sim.executed)
    # every line carried out once, in order; the probe was carried out by the board that
    # counted from 1, refused by the one that kept counting
    assert job_lines(executed) == lines
    assert [executed[at] for at in starts] == ["M105", "M110 N0", "M105"]


def test_the_daemon_s_printer_link_reports_a_boot_it_did_not_see(tmp_path: Path) -> None:
    boots: list[int] = []

    async def connect(sim: SimulatedPrinter) -> None:
        # no banner is coming from a board that does not reset on opening: not waited for
        printer = {"port": sim.path, "baud": 250000, "link": {"start_timeout_s": 0.1}}
        config = config_from_mapping({"printer": printer}, tmp_path)
        async with printer_link(config, lambda: boots.append(1)) as link:
            await link.send("G1 X5 F3000")
            await link.drain()

    with SimulatedPrinter(sim_config(reset_on_open=False)) as sim:
        asyncio.run(connect(sim))
        assert boots == [1]  # switched on before the daemon came
        asyncio.run(connect(sim))
        assert boots == [1]  # the daemon restarted, the printer kept its power
        sim.reset()
        wait_until(lambda: sim.last_line == 0, 5, "the printer to reboot")
        asyncio.run(connect(sim))
        assert boots == [1, 1]  # rebooted meanwhile: a resume goes back replay_lines


def test_the_daemon_s_printer_link_is_served_and_hears_every_banner(tmp_path: Path) -> None:
    # the boot watch is the link's: the daemon's link reads the port from its read
    # callback (no task switch per line), and a reboot mid-print is still reported
    boots: list[int] = []
    served: list[bool] = []
    counts: list[int] = []

    async def connect(sim: SimulatedPrinter) -> None:
        printer = {"port": sim.path, "baud": 250000}
        config = config_from_mapping({"printer": printer}, tmp_path)
        booted = asyncio.Event()

        def on_boot() -> None:
            boots.append(1)
            booted.set()

        async with printer_link(config, on_boot) as link:
            served.append(link.served)
            at_connect = len(boots)
            await link.send("G1 X5 F3000")
            await link.drain()
            counts.append(at_connect)
            booted.clear()
            sim.reset()
            async with asyncio.timeout(10):
                await booted.wait()  # its banner, once it booted
            for x in range(6, 12):
                await link.send(f"G1 X{x} F3000")
            await link.drain()
            served.append(link.served)

    with SimulatedPrinter(sim_config()) as sim:
        asyncio.run(connect(sim))
    assert served == [True, True]
    # at connect: the banner, and the numbering that starts at 1 (the same news twice);
    # then the reboot's banner, once
    assert counts == [2]
    assert len(boots) == 3
