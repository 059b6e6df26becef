"""Acknowledgements across line renumbering (M110): one Ack per job line, once, in order."""

from __future__ import annotations

import asyncio

import pytest
from support.linkrun import arc_job as job
from support.streaming import FAST, job_lines, sim_config

from drivers.link.streamer import Streamer, StreamerConfig
from drivers.link.transport import open_transport
from drivers.sim.printer import SimulatedPrinter

LINES = 4500
RENUMBER_AT = 1000  # the smallest StreamerConfig accepts: four renumbers in LINES
CONFIG = StreamerConfig(**{**FAST.__dict__, "renumber_at": RENUMBER_AT})


async def _stream(sim: SimulatedPrinter, lines: list[str]) -> tuple[Streamer, list, list]:
    """Stream ``lines`` (tagged by index); returns the closed link, the (number, command)
    of each acknowledgement and the send() numbers."""
    numbers: list[int] = []
    transport = await open_transport(sim.path, 250000)
    async with Streamer(transport, CONFIG) as link:
        with link.acknowledgements() as channel:
            await link.connect()
            for index, line in enumerate(lines):
                numbers.append(await link.send(line, tag=index))
            await link.drain()
            received = channel.take()
    assert [ack.tag for ack in received] == list(range(len(lines)))
    return link, [(ack.number, ack.command) for ack in received], numbers


def _check(sim: SimulatedPrinter, lines: list[str], link: Streamer, acks: list,
           numbers: list[int]) -> None:
    executed = list(sim.executed)
    assert job_lines(executed) == lines  # every line executed once, in order
    assert link.stats.renumbers >= 4
    # every renumbering's M110 ran; one whose ok was lost is written again after
    # renumber_retry_s of silence (counted as a probe) and runs again, harmlessly: how
    # often depends on the load (an exact count failed on a loaded machine)
    assert 1 + link.stats.renumbers <= executed.count("M110 N0") \
        <= 1 + link.stats.renumbers + link.stats.probes
    # one Ack per job line, in order, with its command and the number it was sent as
    assert [command for _, command in acks] == lines
    assert [number for number, _ in acks] == numbers
    assert link.acked == len(lines)
    # the numbers really restarted: they never reach renumber_at
    assert max(numbers) < RENUMBER_AT
    assert numbers.count(numbers[-1]) > 1


def test_every_line_is_acknowledged_across_renumbers():
    lines = job(LINES, seed=3)
    with SimulatedPrinter(sim_config()) as sim:
        link, acks, numbers = asyncio.run(_stream(sim, lines))
        _check(sim, lines, link, acks, numbers)


@pytest.mark.parametrize("kind", ["corrupt_rx", "drop_ok", "resend"])
def test_every_line_is_acknowledged_across_renumbers_with_faults(kind):
    lines = job(LINES, seed=7)
    with SimulatedPrinter(sim_config(seed=13, **{f"p_{kind}": 0.01})) as sim:
        link, acks, numbers = asyncio.run(_stream(sim, lines))
        fired = sim.stats().faults
        _check(sim, lines, link, acks, numbers)
    assert fired.get(kind, 0) >= 10  # the faults really happened


def test_every_line_is_acknowledged_across_renumbers_with_combined_faults():
    lines = job(LINES, seed=9)
    kinds = ("corrupt_rx", "drop_ok", "resend")
    with SimulatedPrinter(sim_config(seed=17, **{f"p_{k}": 0.01 for k in kinds})) as sim:
        link, acks, numbers = asyncio.run(_stream(sim, lines))
        fired = sim.stats().faults
        _check(sim, lines, link, acks, numbers)
    assert all(fired.get(k, 0) >= 10 for k in kinds), fired
