"""Fault injection end to end (pty, threads, real time): lines at p = 1 % per fault kind and
combined, executed exactly once, in order.

The protocol core's own fault runs on the virtual clock (``tests/test_drivers_core.py``:
100,000 lines with every kind, resets, interleavings) prove the rules; these runs prove the
asyncio shell, the transport and the pty simulator carry them out, so they stay short:
4,000 lines per kind, 8,000 for disconnects (a pty-only fault) and the combinations.
"""

from __future__ import annotations

import asyncio
import itertools
import time

import pytest
from support.linkrun import arc_job as job
from support.streaming import FAST, job_lines, sim_config, stream_job

from drivers.link.streamer import Streamer, StreamerConfig
from drivers.link.transport import open_transport
from drivers.sim.printer import SimulatedPrinter

LINES = 4_000  # a kind the virtual-clock runs cover too
LONG = 8_000  # disconnects (pty only) and the combinations
P = 0.01
# after a reconnect the board (self-powered here) prints no `start`: wait for it briefly
CONFIG = StreamerConfig(**{**FAST.__dict__, "start_timeout_s": 0.01})


def _run(tmp_path, seed: int, n: int, **faults: float) -> tuple[list[str], dict[str, int],
                                                                object]:
    lines = job(n, seed=seed)
    link_path = str(tmp_path / "printer") if faults.get("p_disconnect") else None
    # the board keeps running when its cable is pulled (self-powered), so its line number
    # survives; a board that resets on every open is covered in test_drivers_streamer.py
    config = sim_config(seed=seed, link_path=link_path, reconnect_delay_s=0.002,
                        reset_on_open=link_path is None, **faults)
    with SimulatedPrinter(config) as sim:
        link = asyncio.run(stream_job(sim, lines, CONFIG, port=link_path))
        executed = list(sim.executed)
        fired = sim.stats().faults
    assert job_lines(executed) == lines
    return executed, fired, link


@pytest.mark.parametrize(
    "kind", ["corrupt_rx", "corrupt_tx", "drop_ok", "resend", "busy", "reset", "disconnect"]
)
def test_each_fault_kind_at_one_percent(tmp_path, kind):
    n = LONG if kind == "disconnect" else LINES
    _, fired, link = _run(tmp_path, seed=11, n=n, **{f"p_{kind}": P})
    assert fired.get(kind, 0) >= n // 200  # the faults really happened (about n / 100)
    assert link.acked == n
    if kind == "corrupt_rx":
        # lines still on the wire after a refused one are refused too, or drained: one
        # replay each time (on a loaded machine probes overflow the buffer now and then:
        # refusals too)
        assert link.stats.lines_resent < 4 * max(fired[kind], link.stats.errors)


def test_all_faults_combined_but_resets(tmp_path):
    kinds = ["corrupt_rx", "corrupt_tx", "drop_ok", "resend", "busy", "disconnect"]
    _, fired, _ = _run(tmp_path, seed=23, n=LONG, **{f"p_{k}": P for k in kinds})
    assert all(fired.get(k, 0) >= LONG // 400 for k in kinds), fired


def test_all_faults_combined_but_lost_oks(tmp_path):
    # A reset right after a lost ok cannot be told from a reset before that line ran, by
    # any host: Marlin gives no other sign that the line was executed. So resets are
    # combined with everything but dropped oks.
    kinds = ["corrupt_rx", "corrupt_tx", "resend", "busy", "reset"]
    _, fired, _ = _run(tmp_path, seed=29, n=LONG, **{f"p_{k}": P for k in kinds})
    assert all(fired.get(k, 0) >= LONG // 400 for k in kinds), fired


def test_an_emulations_request_for_the_next_line_costs_no_silence(tmp_path):
    # OctoPrint's virtual printer style: the last line taken is refused as if it were the
    # next ("Last Line: L", "Resend: L+1", "ok"), and that ok is the only one L gets; like
    # that emulation, the printer keeps its receive buffer after an error. At the link's
    # own 5 s probe interval every such request cost a 5 s stall (27 lines/s)
    lines = job(1_500, seed=5)
    config = sim_config(seed=5, p_refuse_next=0.05, discard_after_error=False)
    link_config = StreamerConfig(**{**FAST.__dict__, "probe_after_s": 5.0,
                                    "busy_silence_s": 4.0})
    stamps: list[float] = []

    async def run() -> Streamer:
        transport = await open_transport(sim.path, 250000)
        write = transport.write_now  # (every write of the link's goes through it)

        def timed(data: bytes) -> None:
            stamps.append(time.monotonic())
            write(data)

        transport.write_now = timed  # type: ignore[method-assign]
        async with Streamer(transport, link_config) as link:
            await link.connect()
            start = len(stamps)
            for line in lines:
                await link.send(line)
            await link.drain()
        del stamps[:start]
        return link

    with SimulatedPrinter(config) as sim:
        link = asyncio.run(run())
        executed = list(sim.executed)
        fired = sim.stats().faults
    assert job_lines(executed) == lines
    assert link.acked == len(lines)
    assert fired.get("refuse_next", 0) >= 30
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert max(gaps) < 0.5, f"a {max(gaps):.2f} s gap between writes"
