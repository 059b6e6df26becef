"""The flow-controlled streamer: numbered lines, send-ahead window, resends, timeouts, control."""

from __future__ import annotations

import asyncio
import contextlib
import re
from collections import deque
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass, field
from types import TracebackType

from drivers.linkconfig import (
    CANCELLED,
    CONNECTING,
    DISCONNECTED,
    ERROR,
    HALTED,
    LONG_COMMANDS,
    PAUSED,
    READY,
    RECONNECTING,
    LinkError,
    StreamCancelled,
    StreamerConfig,
    StreamStats,
)
from drivers.protocol import Response, frame, parse_response
from drivers.resend import recover, resolve_resend
from drivers.transport import Transport, TransportError
from drivers.window import InFlight, SendWindow

__all__ = [
    "CANCELLED",
    "CONNECTING",
    "DISCONNECTED",
    "ERROR",
    "HALTED",
    "LONG_COMMANDS",
    "PAUSED",
    "READY",
    "RECONNECTING",
    "LinkError",
    "StreamCancelled",
    "StreamStats",
    "Streamer",
    "StreamerConfig",
]


# most oks awaited for an M110 written several times
_MAX_LATE_OKS = 8

# the echo of one of our framed lines whose leading N noise turned into another character:
# the printer ran it as an unknown command (its checksum may be stripped from the echo)
_GARBLED_N = re.compile(r'unknown command:\s*"?[^\d\s"](\d+) ', re.IGNORECASE)


@dataclass
class _Renumber:
    """An ``M110`` in progress: written as line ``line``, sets the last line to ``value``."""

    line: int
    value: int
    keep_history: bool
    waiter: asyncio.Future[int] | None = None
    sent: bool = False
    sent_at: float = 0.0
    quiet: bool = False
    writes: int = 0  # times the M110 was written
    refusals: int = 0  # resend requests while it was out (each may stand for a write)

    def late_oks(self) -> int:
        """Oks still to come for the writes the completing ok did not answer: every write
        is answered once, by an ok or by a refusal (counted generously, so that a line of
        the new numbering is never taken for one)."""
        return max(0, self.writes - 1 - self.refusals)


@dataclass
class _Control:
    command: str
    internal: bool
    probe: bool = False
    force: bool = False
    waiter: asyncio.Future[int] | None = field(default=None, repr=False)


class Streamer:
    """Streams G-code commands to a Marlin-style printer, each executed once, in order.

    Use as an async context manager around a :class:`~drivers.transport.Transport` (closed
    on exit)::

        async with Streamer(await open_transport(port, baud), StreamerConfig()) as link:
            await link.connect()
            for command in commands:
                await link.send(command)
            await link.drain()

    Callbacks (attributes, may be set any time): ``on_ack(number, command)`` for every job
    line acknowledged, in order; ``on_temperature(response)`` for every temperature report;
    ``on_error(text)`` for printer errors and link failures.
    """

    def __init__(
        self,
        transport: Transport,
        config: StreamerConfig | None = None,
        *,
        reopen: Callable[[], Awaitable[Transport]] | None = None,
    ) -> None:
        """``reopen`` opens the port again after it was lost (default: same port and speed)."""
        self.config = config or StreamerConfig()
        self.on_ack: Callable[[int, str], None] | None = None
        self.on_temperature: Callable[[Response], None] | None = None
        self.on_error: Callable[[str], None] | None = None
        self.stats = StreamStats()
        self.capabilities: dict[str, str] = {}
        self.firmware = ""
        self.acked = 0
        self.state = DISCONNECTED
        self.error: str | None = None
        self._transport = transport
        self._reopen = reopen
        self._window = SendWindow(self.config.rx_buffer, self.config.bufsize)
        self._history: dict[int, tuple[str, bool]] = {}
        self._next_number = 1
        self._replay_next: int | None = None
        self._last_acked_number = 0
        self._control: deque[_Control] = deque()
        self._pending: deque[tuple[str, asyncio.Future[int]]] = deque()
        self._renumber: _Renumber | None = None
        self._expect_resend_ok = False
        self._last_error: Response | None = None  # a line error just before this line
        self._unconfirmed: tuple[int, int] = (-1, 0)
        self._emitted_through = 0
        self._waiters: dict[int, asyncio.Future[int]] = {}
        self._handshaking = False
        self._rewind_to: int | None = None
        self._force_replay = False  # a probe is due: replay past the window, then probe
        self._late_oks = 0  # oks of M110s written again, still to come and not counted
        self._stale = 0
        self._implausible: tuple[str, int] = ("", 0)
        self._advanced_ok = False
        self._paused = False
        self._cancelled = False
        self._started = asyncio.Event()
        self._wake = asyncio.Event()
        self._progress = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._last_rx = 0.0
        self._last_poll = 0.0
        self._probes_unanswered = 0
        self._reconnected_at = 0.0

    # -- context manager ------------------------------------------------------------------

    async def __aenter__(self) -> Streamer:
        self._start_tasks()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    async def close(self) -> None:
        """Stop the link's tasks, fail every waiter and close the transport."""
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks.clear()
        self._fail_waiters(LinkError("link closed"))
        await self._transport.close()
        if self.state not in (ERROR, HALTED):
            self.state = DISCONNECTED

    # -- public API -----------------------------------------------------------------------

    @property
    def capable(self) -> frozenset[str]:
        """Names of the capabilities the firmware reported as enabled (``Cap:NAME:1``)."""
        return frozenset(k for k, v in self.capabilities.items() if v == "1")

    @property
    def in_flight(self) -> int:
        """Lines written and not yet acknowledged."""
        return len(self._window)

    async def connect(self) -> None:
        """Wait for ``start`` (or a timeout), then ``M110 N0``, ``M115`` and auto-report.

        Raises :class:`LinkError` if the printer does not answer in ``connect_timeout_s``.
        """
        self._start_tasks()
        self.state = CONNECTING
        loop = asyncio.get_running_loop()
        self._last_rx = loop.time()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._started.wait(), self.config.start_timeout_s)
        with contextlib.suppress(TransportError):
            await self._transport.write(b"\n")  # end any noise the printer has buffered
        self._handshaking = True  # from now on a `start` is a reset to recover from
        try:
            async with asyncio.timeout(self.config.connect_timeout_s):
                await self._handshake(reset_to=0, keep_history=False)
                await self._control_line("M115")
                if "AUTOREPORT_TEMP" in self.capable and self.config.temperature_interval_s > 0:
                    seconds = max(1, round(self.config.temperature_interval_s))
                    await self._control_line(f"M155 S{seconds}")
        except TimeoutError as exc:
            self._fail("printer did not answer the connection handshake")
            raise LinkError(self.error) from exc
        self.state = PAUSED if self._paused else READY
        self._last_poll = loop.time()

    async def send(self, command: str) -> int:
        """Queue one job command; returns its line number once it has been written.

        Waits while the send-ahead window is full or the stream is paused. Raises
        :class:`StreamCancelled` after ``cancel()``, :class:`LinkError` if the link failed.
        """
        command = command.strip()
        if not command:
            raise ValueError("empty command")
        if self._cancelled:
            raise StreamCancelled("stream cancelled")
        self._check_alive()
        future: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._pending.append((command, future))
        self._wake.set()
        return await future

    async def drain(self) -> None:
        """Wait until every line written has been acknowledged."""
        while not self._idle():
            self._check_alive()
            self._progress.clear()
            await self._progress.wait()
        self._check_alive()

    async def pause(self, park: Iterable[str] | None = None) -> None:
        """Stop after the lines already written; then send the park G-code (if any).

        Returns once the printer has acknowledged everything sent. ``park`` overrides
        ``config.park_gcode``.
        """
        self._paused = True
        if self.state == READY:
            self.state = PAUSED
        for command in self.config.park_gcode if park is None else park:
            self._queue_control(command, internal=False)
        self._wake.set()
        await self.drain()

    async def resume(self, unpark: Iterable[str] | None = None) -> None:
        """Send the unpark G-code, then continue exactly where the stream stopped."""
        for command in self.config.unpark_gcode if unpark is None else unpark:
            await self._control_line(command, internal=False)
        self._paused = False
        if self.state == PAUSED:
            self.state = READY
        self._wake.set()

    async def cancel(self, end_gcode: Iterable[str] = ()) -> None:
        """Refuse further job lines, send ``end_gcode`` after what is in flight, drain.

        Pending and later ``send()`` calls raise :class:`StreamCancelled` until
        ``begin_job()`` opens the link to the next job.
        """
        self._cancelled = True
        self._paused = False
        while self._pending:
            _, future = self._pending.popleft()
            if not future.done():
                future.set_exception(StreamCancelled("stream cancelled"))
        for command in end_gcode:
            self._queue_control(command, internal=False)
        self._wake.set()
        await self.drain()
        if self.state not in (ERROR, HALTED):
            self.state = CANCELLED

    def begin_job(self) -> None:
        """Accept job lines again after ``cancel()`` (the link itself stays connected)."""
        self._cancelled = False
        if self.state == CANCELLED:
            self.state = READY
        self._wake.set()

    async def emergency_stop(self) -> None:
        """``M112`` at once: out of band with an emergency parser, else as the next line."""
        if "EMERGENCY_PARSER" in self.capable:
            with contextlib.suppress(TransportError):
                await self._transport.write(b"M112\n")
        else:
            self._control.appendleft(_Control("M112", internal=False, force=True))
            self._replay_next = None
            self._force_replay = False
            self._wake.set()
            await asyncio.sleep(0)
            await self._writer_step()
        self.state = HALTED
        self.error = "emergency stop"
        self._fail_waiters(LinkError("emergency stop"))

    async def interrupt_wait(self) -> None:
        """``M108``: break out of a heating wait or user prompt (out of band when offered)."""
        await self._urgent("M108")

    async def quick_stop(self) -> None:
        """``M410``: stop all moves at once, keeping the printer alive."""
        await self._urgent("M410")

    # -- internals: connection ------------------------------------------------------------

    def _start_tasks(self) -> None:
        if self._tasks:
            return
        self._last_rx = asyncio.get_running_loop().time()
        self._tasks = [
            asyncio.create_task(self._read_loop(), name="streamer-reader"),
            asyncio.create_task(self._write_loop(), name="streamer-writer"),
            asyncio.create_task(self._watch_loop(), name="streamer-watchdog"),
        ]

    async def _handshake(self, reset_to: int, keep_history: bool) -> None:
        """Drain, then ``M110 N<reset_to>`` until acknowledged."""
        waiter: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._renumber = _Renumber(self._next_number, reset_to, keep_history, waiter)
        self._wake.set()
        await waiter

    async def _control_line(self, command: str, internal: bool = True) -> int:
        loop = asyncio.get_running_loop()
        waiter: asyncio.Future[int] = loop.create_future()
        self._queue_control(command, internal=internal, waiter=waiter)
        return await waiter

    def _queue_control(
        self, command: str, *, internal: bool, waiter: asyncio.Future[int] | None = None,
        probe: bool = False, force: bool = False,
    ) -> None:
        self._control.append(_Control(command, internal, probe=probe, force=force, waiter=waiter))
        self._wake.set()

    async def _urgent(self, command: str) -> None:
        if "EMERGENCY_PARSER" in self.capable:
            await self._transport.write(f"{command}\n".encode())
        else:
            self._control.appendleft(_Control(command, internal=False, force=True))
            self._wake.set()

    # -- internals: reading ---------------------------------------------------------------

    async def _read_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            try:
                text = await self._transport.readline()
            except TransportError as exc:
                if not await self._link_lost(str(exc)):
                    return
                continue
            self._last_rx = loop.time()
            self._probes_unanswered = 0
            self._handle(recover(parse_response(text)))

    def _handle(self, response: Response) -> None:
        kind = response.kind
        if kind == "other":
            return  # unreadable noise (a Resend garbled beyond repair): keep what came before
        after_resend = self._expect_resend_ok
        self._expect_resend_ok = False
        error_before = self._last_error
        self._last_error = None
        if kind == "ok":
            if response.has_temperatures:
                self._emit_temperature(response)
            if after_resend:
                return  # the ok Marlin 2.1 sends after every Resend
            if error_before is not None and self.config.ok_after_resend:
                self._on_lost_resend(error_before)  # this is the ok after it
                return
            self._on_ok(response)
        elif kind == "resend":
            self._on_resend(response, error_before)
        elif kind == "error":
            self._on_error(response)
        elif kind == "temperature":
            self._emit_temperature(response)
        elif kind == "echo":
            garbled = _GARBLED_N.match(response.text)
            if garbled and int(garbled.group(1)) in self._history \
                    and not response.text[garbled.end():].startswith("M110"):
                # a line of ours whose leading N was garbled ran as an unknown command;
                # its ok belongs to no line of ours (the line is refused by number later).
                # An M110 is left alone: renumbering counts one ok per write of it, and
                # one that did not take shows as refused lines, which renumber again
                self._expect_resend_ok = True
        elif kind == "capability":
            if response.name == "FIRMWARE_NAME":
                self.firmware = response.value
            else:
                self.capabilities[response.name] = response.value
        elif kind == "start":
            if self.state == CONNECTING and not self._handshaking:
                self._started.set()
            elif self.state == RECONNECTING:
                self.state = PAUSED if self._paused else READY
                self._on_reset()
            else:
                self._on_reset()

    def _on_ok(self, response: Response) -> None:
        if response.has_temperatures:
            self._late_oks = 0  # a probe's answer: any late ok came before it
        elif self._late_oks:
            self._late_oks -= 1
            return
        if response.queue_free is not None:
            self._advanced_ok = True
            if self.config.learn_bufsize:
                self._window.max_lines = max(self._window.max_lines, response.queue_free + 1)
        # oks are counted in order; an advanced ok's N is not trusted to name the line it
        # acknowledges (firmwares print the last line received or the one executed)
        ack = self._window.ack_probe if response.has_temperatures else self._window.ack_one
        for entry in ack():
            self._acknowledged(entry)
        self._wake.set()
        self._progress.set()

    def _acknowledged(self, entry: InFlight) -> None:
        """Record one line as done, in the numbering it was written under.

        An ``M110`` that completes a renumbering is recorded like any line, in the old
        numbering, and only then starts the new one, so that the records kept by line number
        (``_last_acked_number``, ``_emitted_through``) end as the new numbering sets them.
        """
        number = entry.number
        repeated = number is not None and number <= self._emitted_through
        if number is not None:
            self._last_acked_number = max(self._last_acked_number, number)
            if not repeated:
                self._emitted_through = number
        if not entry.internal and not repeated:  # not again when replayed after a refusal
            self.acked += 1
            if self.on_ack is not None:
                self.on_ack(number if number is not None else -1, entry.command)
        waiter = entry.waiter
        if number is not None:
            # a line replayed after a refusal or reset is a new entry: its waiter is by number
            waiter = self._waiters.pop(number, waiter)
        if waiter is not None and not waiter.done():
            waiter.set_result(number if number is not None else -1)
        if self._completes_renumber(entry):
            self._finish_renumber()

    def _completes_renumber(self, entry: InFlight) -> bool:
        """True if ``entry`` is the ``M110`` of the renumbering in progress."""
        renumber = self._renumber
        return (renumber is not None and renumber.sent and entry.number == renumber.line
                and entry.command.startswith("M110"))

    def _finish_renumber(self) -> None:
        """The printer took the ``M110``: continue in the numbering it set (every record
        kept by line number is set for it here)."""
        renumber = self._renumber
        assert renumber is not None
        value, keep = renumber.value, renumber.keep_history
        self._renumber = None
        if renumber.waiter is not None and not renumber.waiter.done():
            renumber.waiter.set_result(value)
        self._rewind_to = None
        self._stale = 0
        if keep and value + 1 < self._next_number:
            self._replay_next = value + 1
        else:
            self._history.clear()
            self._next_number = value + 1
            self._replay_next = None
            self._force_replay = False
            self._emitted_through = value
            # resend requests counted against the old numbers name other lines now
            self._unconfirmed = (-1, 0)
            self._implausible = ("", 0)
        self._last_acked_number = value
        # an M110 written again after silence may have its first ok still to come, before
        # any ok of the lines that follow: those oks are not counted for them
        self._late_oks = min(renumber.late_oks(), _MAX_LATE_OKS)

    def _on_resend(self, response: Response, error_before: Response | None) -> None:
        """``Resend: N``: replay from N, when the request is sane.

        The number is checked against the lines that can be asked for (unacknowledged or
        next), repaired when digits were lost, confirmed by the ``Error`` line before it or
        by repetition; further requests for the same error (lines that were still on the
        wire) are answered once; a request for an acknowledged line means lost state.
        """
        # Marlin follows Error + Resend with an ok (2.1; some 2.0 builds do not)
        self._expect_resend_ok = error_before is not None and self.config.ok_after_resend
        error_line = error_before.line if error_before is not None else None
        self.stats.resends += 1
        if self._renumber is not None:
            if self._renumber.writes:
                self._renumber.refusals += 1
            # M110 skips the line-number check, so only a checksum error can refuse it; a
            # line-number error comes from a line sent before it (before the reset)
            refused = error_before is not None and error_before.error_kind != "line_number"
            if self._renumber.sent and refused:
                self._window.clear()
                self._renumber.sent = False
                self._wake.set()
            else:
                self.stats.duplicate_resends += 1
            return
        low = min([*self._window.numbers(), self._last_acked_number + 1, self._next_number])
        candidates = range(low, self._next_number + 1)
        number = resolve_resend(response.digits, candidates, error_line)
        if number is None:
            number = self._repeated_implausible(response, error_line)
            if number is None:
                self.stats.implausible_resends += 1
                return
        self._implausible = ("", 0)
        if error_before is None and not self._confirm_unannounced(number):
            return
        if number <= self._last_acked_number:
            if self._last_acked_number - number > self._window.max_lines + 4 \
                    or number not in self._history:
                # far behind what it acknowledged: the printer lost its line number
                self._on_reset()
                return
            # an ok counted for a line the printer refused (a mangled line it answered
            # as an unknown command): take the acknowledgement back and replay
            self._last_acked_number = number - 1
        if number == self._rewind_to and self._stale > 0:
            self._stale -= 1
            self.stats.duplicate_resends += 1
            return
        if number >= self._next_number:
            return  # the printer has every line sent: nothing to replay
        dropped = self._window.drop_from(number)
        self._rewind_to = number
        self._stale = max(0, len(dropped) - 1)
        self._replay_next = number
        self._wake.set()

    def _on_lost_resend(self, error: Response) -> None:
        """An ``Error`` then its ``ok``, the ``Resend`` between them lost to noise: act on
        the request the error implies (the line after its ``Last Line``), so that a refused
        ``M110`` counts as refused and a refused line is replayed."""
        digits = str(error.line + 1) if error.line is not None else ""
        implied = Response("resend", f"Resend: {digits}", line=error.line + 1 if digits else None,
                           digits=digits)
        self._on_resend(implied, error)
        self._expect_resend_ok = False  # its ok is the one being read

    def _confirm_unannounced(self, number: int) -> bool:
        """Marlin announces every resend with an ``Error:`` line. A request without one (the
        error line lost to noise, or a spurious request) is obeyed only when repeated: if
        the printer really lacks the line, it refuses the next line with an error."""
        previous, count = self._unconfirmed
        count = count + 1 if previous == number else 1
        self._unconfirmed = (number, count)
        if count >= 2:
            self._unconfirmed = (-1, 0)
            return True
        self.stats.unconfirmed_resends += 1
        return False

    def _repeated_implausible(self, response: Response, error_line: int | None) -> int | None:
        """A request repeated three times, or confirmed by the error's ``Last Line``, for a
        line not yet acknowledged and still held, is obeyed after all; one for an
        acknowledged line is returned too (the caller treats it as lost state)."""
        digits, count = self._implausible
        count = count + 1 if digits == response.digits else 1
        self._implausible = (response.digits, count)
        number = response.line
        if number is None or number > self._next_number:
            return None
        confirmed = error_line is not None and error_line + 1 == number
        if count >= 3 or confirmed:
            self._implausible = ("", 0)
            if number <= self._last_acked_number or number in self._history:
                return number
        return None

    def _on_error(self, response: Response) -> None:
        self.stats.errors += 1
        if response.error_kind in ("checksum", "line_number", "no_checksum", "no_line_number"):
            self._last_error = response
            return
        if response.error_kind in ("halted", "stopped"):
            self.state = HALTED
            self.error = response.text
            self._report(response.text)
            self._fail_waiters(LinkError(f"printer stopped: {response.text}"))
            return
        self._report(response.text)

    def _on_reset(self) -> None:
        """``start`` mid-stream: the printer rebooted and lost its buffers and line number."""
        self.stats.resets += 1
        # requests seen before the reboot confirm nothing after it
        self._unconfirmed = (-1, 0)
        self._implausible = ("", 0)
        if self._renumber is None:
            value = self._last_acked_number
            self._renumber = _Renumber(value, value, keep_history=True, quiet=True)
        self._forget_in_flight()
        self._wake.set()

    def _forget_in_flight(self) -> None:
        """Whatever was on the wire or in the printer's buffers is gone (reset or cut):
        nothing in flight, no replay under way, an ``M110`` in progress to be written anew."""
        self._window.clear()
        self._rewind_to = None
        self._stale = 0
        self._replay_next = None
        self._force_replay = False
        self._late_oks = 0
        if self._renumber is not None:
            self._renumber.sent = False
            self._renumber.writes = self._renumber.refusals = 0

    async def _link_lost(self, reason: str) -> bool:
        """The port failed: report, then try to reopen. True if the link is back."""
        self.state = DISCONNECTED
        self._report(f"link lost: {reason}")
        for _attempt in range(self.config.reconnect_attempts):
            await asyncio.sleep(self.config.reconnect_delay_s)
            try:
                transport = await self._open_again()
            except TransportError:
                continue
            self._transport = transport
            self.stats.reconnects += 1
            with contextlib.suppress(TransportError):
                # end whatever partial line the printer kept from before the cut
                await transport.write(b"\n")
            self._reconnected_at = self._last_rx = asyncio.get_running_loop().time()
            self._forget_in_flight()
            self.state = RECONNECTING  # until `start` (the board reset) or start_timeout_s
            return True
        self._fail(f"link lost: {reason}")
        return False

    async def _open_again(self) -> Transport:
        if self._reopen is not None:
            return await self._reopen()
        from drivers.transport import open_transport

        return await open_transport(self._transport.name, self._baud())

    def _baud(self) -> int:
        return int(getattr(getattr(self._transport, "_port", None), "baudrate", 250000))

    # -- internals: writing ---------------------------------------------------------------

    async def _write_loop(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            await self._writer_step()

    async def _writer_step(self) -> None:
        while self.state not in (ERROR, HALTED, DISCONNECTED, RECONNECTING):
            out = self._next_line()
            if out is None:
                return
            data, entry = out
            try:
                await self._transport.write(data)
            except TransportError:
                return  # the reader reports the failure
            if entry is not None:
                self._window.push(entry)
            self.stats.lines_sent += 1
            self.stats.bytes_sent += len(data)

    def _next_line(self) -> tuple[bytes, InFlight | None] | None:
        """The next line to write, if the window and state allow one."""
        if self._renumber is not None:
            return self._next_renumber_line()
        if self._replay_next is not None:
            return self._next_replay_line()
        if self._control:
            return self._next_control_line()
        if self._pending and not self._paused and not self._cancelled:
            if self._next_number >= self.config.renumber_at:
                if len(self._window):
                    # drain first, outside the renumbering: until the M110 is written the
                    # printer keeps the old numbers, and a probe must recover a lost ok
                    return None
                self.stats.renumbers += 1
                self._renumber = _Renumber(self._next_number, 0, keep_history=False)
                return self._next_renumber_line()
            command, future = self._pending[0]
            data = frame(self._next_number, command)
            if not self._window.has_room(len(data)):
                return None
            self._pending.popleft()
            number = self._assign(command)
            if not future.done():
                future.set_result(number)
            return data, InFlight(number, command, len(data))
        return None

    def _next_renumber_line(self) -> tuple[bytes, InFlight | None] | None:
        """``M110`` once nothing else is in flight; only forced lines pass it."""
        renumber = self._renumber
        assert renumber is not None
        if self._control and self._control[0].force and not self._control[0].probe:
            return self._next_control_line()
        if renumber.sent or len(self._window):
            return None
        if renumber.quiet and \
                asyncio.get_running_loop().time() - self._last_rx < self.config.resync_quiet_s:
            return None  # let replies to lines sent before the reset arrive first
        command = f"M110 N{renumber.value}"
        data = frame(renumber.line, command)
        renumber.sent = True
        renumber.writes += 1
        renumber.sent_at = asyncio.get_running_loop().time()
        return data, InFlight(renumber.line, command, len(data), internal=True)

    def _next_replay_line(self) -> tuple[bytes, InFlight | None] | None:
        number = self._replay_next
        assert number is not None
        if self._control and self._control[0].force and not self._control[0].probe:
            return self._next_control_line()
        held = self._history.get(number)
        if held is None:
            self._fail(f"printer asked for line {number}, which is no longer held")
            return None
        command, internal = held
        data = frame(number, command)
        if not self._force_replay and not self._window.has_room(len(data)):
            return None
        self._replay_next = number + 1 if number + 1 < self._next_number else None
        if self._replay_next is None:
            self._force_replay = False
        self.stats.lines_resent += 1
        return data, InFlight(number, command, len(data), internal=internal,
                              probe=command == "M105" and internal)

    def _next_control_line(self) -> tuple[bytes, InFlight | None] | None:
        control = self._control[0]
        data = frame(self._next_number, control.command)
        if not control.force and not self._window.has_room(len(data)):
            return None
        self._control.popleft()
        number = self._assign(control.command, internal=control.internal)
        if control.waiter is not None:
            self._waiters[number] = control.waiter
        return data, InFlight(number, control.command, len(data), internal=control.internal,
                              probe=control.probe, waiter=control.waiter)

    def _assign(self, command: str, internal: bool = False) -> int:
        number = self._next_number
        self._next_number += 1
        self._history[number] = (command, internal)
        self._history.pop(number - self.config.history, None)
        return number

    # -- internals: watchdog --------------------------------------------------------------

    async def _watch_loop(self) -> None:
        loop = asyncio.get_running_loop()
        tick = min(0.25, self.config.probe_after_s / 4)
        if self.config.temperature_interval_s > 0:
            tick = min(tick, self.config.temperature_interval_s / 4)
        while True:
            await asyncio.sleep(tick)
            if self.state in (ERROR, HALTED, DISCONNECTED):
                continue
            now = loop.time()
            if self.state == RECONNECTING:
                self._watch_reconnect(now)
                continue
            self._watch_silence(now)
            self._watch_temperature(now)

    def _watch_reconnect(self, now: float) -> None:
        """No ``start`` after reopening: the printer kept its state; continue after the
        last acknowledged line (it refuses, by line number, anything it already has)."""
        if now - self._reconnected_at < self.config.start_timeout_s:
            return
        self.state = PAUSED if self._paused else READY
        if self._renumber is None and self._last_acked_number + 1 < self._next_number:
            self._replay_next = self._last_acked_number + 1
        self._wake.set()

    def _watch_silence(self, now: float) -> None:
        renumber = self._renumber
        if renumber is not None and not renumber.sent:
            self._wake.set()  # a resynchronisation waits for a quiet line
        if renumber is not None and renumber.sent:
            if now - max(self._last_rx, renumber.sent_at) >= self.config.renumber_retry_s:
                self._window.clear()  # M110 is idempotent: write it again
                renumber.sent = False
                self._probes_unanswered += 1
                self.stats.probes += 1
                if self._probes_unanswered > self.config.probe_retries:
                    self._fail("printer does not answer M110")
                self._wake.set()
            return
        if not len(self._window):
            return
        silence = now - self._last_rx
        long_running = any(e.command.split(" ", 1)[0] in LONG_COMMANDS for e in self._window)
        due = self.config.probe_after_s * (self._probes_unanswered + 1)
        if silence < due:
            return
        if long_running:
            if silence >= self.config.long_command_timeout_s:
                self._fail(f"printer silent for {silence:.0f} s during a long command")
            elif self._probes_unanswered == 0:
                self._probe()
            return
        if self._probes_unanswered >= self.config.probe_retries:
            self._fail(f"printer not responding ({self._probes_unanswered} probes unanswered)")
            return
        self._probe()

    def _probe(self) -> None:
        """Ask ``M105`` past the window: its ``ok T:`` proves every earlier line done.

        One probe at a time: one already queued is only made urgent.
        During a replay the probe waits for the replay to end, numbered after it (a probe
        numbered ahead would be refused), and the replay passes the window meanwhile.
        """
        self._probes_unanswered += 1
        self.stats.probes += 1
        if self._replay_next is not None:
            self._force_replay = True
        queued = next((c for c in self._control if c.probe), None)
        if queued is not None:
            queued.force = True
            self._wake.set()
            return
        self._queue_control("M105", internal=True, probe=True, force=True)

    def _watch_temperature(self, now: float) -> None:
        interval = self.config.temperature_interval_s
        if interval <= 0 or "AUTOREPORT_TEMP" in self.capable or self.state == CONNECTING:
            return
        if now - self._last_poll < interval:
            return
        self._last_poll = now
        if any(e.probe for e in self._window) or any(c.probe for c in self._control):
            return
        self._queue_control("M105", internal=True, probe=True)

    # -- internals: state -----------------------------------------------------------------

    def _idle(self) -> bool:
        return (not len(self._window) and not self._control
                and self._replay_next is None and self._renumber is None)

    def _check_alive(self) -> None:
        if self.state in (ERROR, HALTED):
            raise LinkError(self.error or "link failed")

    def _fail(self, reason: str) -> None:
        if self.state in (ERROR, HALTED):
            return
        self.state = ERROR
        self.error = reason
        self._report(reason)
        self._fail_waiters(LinkError(reason))

    def _fail_waiters(self, error: Exception) -> None:
        while self._pending:
            _, future = self._pending.popleft()
            if not future.done():
                future.set_exception(error)
        for control in self._control:
            if control.waiter is not None and not control.waiter.done():
                control.waiter.set_exception(error)
        self._control.clear()
        for entry in self._window:
            if entry.waiter is not None and not entry.waiter.done():
                entry.waiter.set_exception(error)
        for waiter in self._waiters.values():
            if not waiter.done():
                waiter.set_exception(error)
        self._waiters.clear()
        self._progress.set()

    def _report(self, text: str) -> None:
        if self.on_error is not None:
            self.on_error(text)

    def _emit_temperature(self, response: Response) -> None:
        if self.on_temperature is not None:
            self.on_temperature(response)

