"""The printer connection: the built-in simulated printer or a serial port, behind a Streamer."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator, Callable

from drivers.link.streamer import Streamer
from drivers.link.transport import open_transport
from drivers.sim.config import SimulatorConfig
from drivers.sim.printer import SimulatedPrinter
from hostd.config import Config
from hostd.printing.printermotion import motion_note

log = logging.getLogger("hostd.printing.printer")

SIM_LOG = "simulator-executed.log"


@contextlib.asynccontextmanager
async def printer_link(
    config: Config, on_boot: Callable[[], None] | None = None
) -> AsyncIterator[Streamer]:
    """Open the configured printer and yield a connected streamer; close everything on exit.

    ``on_boot`` is called when the printer booted since its last host: it announced
    a boot (``start``) while connecting (it reset on opening the port, or was just
    switched on), or its line numbering starts at 1 again although its banner went
    unread (it rebooted while no host had the port open: power cut, reset button;
    :mod:`drivers.link.numbering`). A printer that kept its power is told by the lines of
    the last session it still counts.

    ``port = "sim"`` starts the simulated printer in-process on a pseudo-terminal,
    at ``[simulator]`` speed, logging every executed line to
    ``<state>/simulator-executed.log`` (and keeping none in memory).
    """
    simulator: SimulatedPrinter | None = None
    port = config.printer.port
    baud = config.printer.baud
    if port == "sim":
        config.state.folder.mkdir(parents=True, exist_ok=True)
        simulator = SimulatedPrinter(
            SimulatorConfig(
                time_scale=config.simulator.time_scale,
                baud=config.simulator.baud,
                acceleration=config.simulator.acceleration,
                log_path=str(config.state.folder / SIM_LOG),
                keep_executed=False,  # in the log: a list in memory grew by every line
            )
        )
        port = simulator.start()
        log.info("simulated printer on %s (time scale %g, baud %d, acceleration %g mm/s²)",
                 port, config.simulator.time_scale, config.simulator.baud,
                 config.simulator.acceleration)
    try:
        transport = await open_transport(port, baud)
        async with Streamer(transport, config.printer.link) as streamer:
            # (told by the link, not by a wrapper around the port: the link reads the
            # port itself, from its read callback, and a port reopened keeps the watch)
            streamer.on_boot = on_boot
            await streamer.connect(probe_numbering=on_boot is not None)
            if streamer.numbering_kept is False and on_boot is not None:
                on_boot()  # (again, if its banner was read too: the same news)
            log.info("printer connected on %s: %s", port, streamer.firmware or "unknown firmware")
            log.info("slicing for this printer: %s", motion_note(config, streamer.motion))
            yield streamer
    finally:
        if simulator is not None:
            simulator.stop()

