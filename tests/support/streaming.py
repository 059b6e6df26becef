"""Streaming helpers the streamer tests share: a fast link configuration, a job streamed to
the simulated printer, and a scripted Marlin-like responder on a pty."""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from collections.abc import Callable

from drivers.link.protocol import checksum
from drivers.link.streamer import Streamer, StreamerConfig
from drivers.link.transport import open_transport
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig

INTERNAL = ("M110", "M115", "M503", "M155", "M105")

# short timeouts so that stalls cost milliseconds with an instant printer; many probes
# before giving up, so that a loaded machine (the simulator starved of CPU) is not "silent"
FAST = StreamerConfig(probe_after_s=0.02, probe_retries=100, resync_quiet_s=0.01,
                      start_timeout_s=0.05,
                      reconnect_attempts=200, reconnect_delay_s=0.005,
                      temperature_interval_s=1.0,
                      # a lost ok that leaves the window full waits this long for its probe
                      busy_silence_s=0.1)


def job_lines(executed: list[str]) -> list[str]:
    """The executed commands that came from the job (the link's own lines removed; a
    probe merged with the line after it by a receive overrun, ``M105*N12 M105``, whose
    checksum still matched, ran as the probe)."""
    return [c for c in executed if c.split(" ", 1)[0].split("*", 1)[0] not in INTERNAL]


async def stream_job(
    sim: SimulatedPrinter,
    lines: list[str],
    config: StreamerConfig = FAST,
    port: str | None = None,
    errors: list[str] | None = None,
) -> Streamer:
    """Connect to ``sim``, stream ``lines``, drain; returns the (closed) streamer."""
    transport = await open_transport(port or sim.path, 250000)
    async with Streamer(transport, config) as link:
        if errors is not None:
            link.on_error = errors.append
        await link.connect()
        for line in lines:
            await link.send(line)
        await link.drain()
    return link


def sim_config(**kw) -> SimulatorConfig:
    base = {"time_scale": 0.0, "baud": 0, "boot_delay_s": 0.0}
    base.update(kw)
    return SimulatorConfig(**base)


# -- scripted responder ----------------------------------------------------------------------

Answer = Callable[[int, str], list[str] | None]


class ScriptedPrinter:
    """A tiny Marlin-like responder on a pty: checks N and checksum, answers ok or Resend.

    ``answer(number, command)`` may return the reply lines for a numbered line (``None``:
    the usual ``ok``; ``[]``: silence; a reply starting with ``Error:`` refuses the line).
    Every received raw line is kept in ``received``; accepted commands in ``executed``.
    """

    def __init__(self, answer: Answer | None = None) -> None:
        self.answer = answer
        self.received: list[str] = []
        self.executed: list[str] = []
        self.last_n = 0
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        os.close(slave)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._serve, name="scripted-printer", daemon=True)
        self._thread.start()

    def close(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join(2)
        for fd in (self._master, self._stop_r, self._stop_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _send(self, lines: list[str]) -> None:
        with contextlib.suppress(OSError):
            os.write(self._master, "".join(f"{line}\n" for line in lines).encode())

    def _serve(self) -> None:
        buffer = b""
        while True:
            ready, _, _ = select.select([self._master, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                data = os.read(self._master, 4096)
            except OSError:
                select.select([self._stop_r], [], [], 0.05)
                continue
            buffer += data
            while b"\n" in buffer:
                raw, buffer = buffer.split(b"\n", 1)
                self._line(raw.decode())

    def _line(self, text: str) -> None:
        if not text.strip():
            return  # blank lines are skipped, as Marlin does
        self.received.append(text)
        if not text.startswith("N"):
            self._run(text.split("*")[0], None)
            return
        body, _, cs = text.rpartition("*")
        number = int(body[1:].split(" ", 1)[0])
        command = body.split(" ", 1)[1]
        if checksum(body) != int(cs):
            self._send([f"Error:checksum mismatch, Last Line: {self.last_n}",
                        f"Resend: {self.last_n + 1}", "ok"])
            return
        if command.startswith("M110"):
            self.last_n = int(command.split("N")[1])
            self._send(["ok"])
            return
        if number != self.last_n + 1:
            self._send([f"Error:Line Number is not Last Line Number+1, Last Line: {self.last_n}",
                        f"Resend: {self.last_n + 1}", "ok"])
            return
        reply = self.answer(number, command) if self.answer else None
        if reply and reply[0].startswith("Error:"):
            self._send(reply)  # refused: not executed, last line unchanged
            return
        self.last_n = number
        self._run(command, number, reply)

    def _run(self, command: str, number: int | None, reply: list[str] | None = None) -> None:
        if reply is not None:
            self._send(reply)
            if reply:
                self.executed.append(command)
            return
        self.executed.append(command)
        if command == "M115":
            self._send(["FIRMWARE_NAME:Scripted 1.0", "ok"])
        elif command == "M105":
            self._send(["ok T:20.0 /0.0 B:20.0 /0.0 @:0 B@:0"])
        else:
            self._send(["ok"])


@contextlib.contextmanager
def scripted(answer: Answer | None = None):
    printer = ScriptedPrinter(answer)
    try:
        yield printer
    finally:
        printer.close()


async def stream_scripted(printer: ScriptedPrinter, lines: list[str],
                          config: StreamerConfig = FAST) -> Streamer:
    async with Streamer(await open_transport(printer.path, 115200), config) as link:
        await link.connect()
        for line in lines:
            await link.send(line)
        await link.drain()
    return link
