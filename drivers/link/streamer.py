"""The streamer: a thin asyncio shell running the protocol core over a serial transport."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable, Hashable, Iterable, Iterator
from types import TracebackType

from drivers.link.acks import Ack, AckChannel, Tags
from drivers.link.config import (
    CANCELLED,
    CONNECTING,
    DISCONNECTED,
    ERROR,
    HALTED,
    LONG_COMMANDS,
    PAUSED,
    READY,
    RECONNECTING,
    StreamerConfig,
    StreamStats,
)
from drivers.link.connect import Reconnector, log_connection
from drivers.link.core import LinkCore
from drivers.link.errors import LinkError, PrinterLinkError, StreamCancelled, TransportError
from drivers.link.events import (
    Acked,
    Booted,
    Event,
    Failed,
    LinkState,
    Report,
    Temperature,
    Written,
)
from drivers.link.motion import PrinterMotion
from drivers.link.profile import Profile
from drivers.link.protocol import Response
from drivers.link.tasks import cancel_and_wait
from drivers.link.transport import Transport
from drivers.link.waiters import Waiters

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
    "Ack",
    "AckChannel",
    "LinkError",
    "LinkState",
    "PrinterLinkError",
    "StreamCancelled",
    "StreamStats",
    "Streamer",
    "StreamerConfig",
    "TransportError",
]

KILL_REPLY_S = 1.0  # an emergency stop out of band waits this long for the halt report
# without an emergency parser, M112 runs once the commands queued before it have been
# taken (each may wait for room in a full planner): the link serves the printer that long
KILL_QUEUED_S = 10.0


class Streamer:
    """Streams G-code commands to a Marlin-style printer, each executed once, in order.

    Use as an async context manager around a :class:`~drivers.link.transport.Transport` (closed
    on exit)::

        async with Streamer(await open_transport(port, baud), StreamerConfig()) as link:
            await link.connect()
            for command in commands:
                await link.send(command)
            await link.drain()

    Acknowledgements come through one typed channel: ``with link.acknowledgements() as
    acks`` attaches an :class:`~drivers.link.acks.AckChannel` that receives an
    :class:`~drivers.link.acks.Ack` for every job line acknowledged, in order, carrying the
    ``tag`` given to ``send()``. Callbacks (attributes): ``on_temperature(response)`` for
    every temperature report; ``on_error(text)`` for printer errors and link failures;
    ``on_boot()`` for every boot banner (``start``) the printer prints.

    Every protocol decision is the core's (:class:`~drivers.link.core.LinkCore`); this shell
    runs three named tasks in one ``TaskGroup``: the reader feeds it received lines, the
    writer writes what it hands out, the watchdog lets time pass. The handshake is the
    core's too (:mod:`drivers.link.handshake`); reopening a lost port is the
    :class:`~drivers.link.connect.Reconnector`'s.
    """

    def __init__(
        self,
        transport: Transport,
        config: StreamerConfig | None = None,
        *,
        reopen: Callable[[], Awaitable[Transport]] | None = None,
    ) -> None:
        """``reopen`` opens the port again after it was lost (default: same port and speed)."""
        self.core = LinkCore(config or StreamerConfig())
        self._acks: AckChannel | None = None
        self._tags = Tags()
        self.on_temperature: Callable[[Response], None] | None = None
        self.on_error: Callable[[str], None] | None = None
        self.on_boot: Callable[[], None] | None = None
        self._transport = transport
        self._reconnector = Reconnector(reopen)
        self._waiters = Waiters()
        self._wake = asyncio.Event()
        self._progress = asyncio.Event()
        self._failed = asyncio.Event()  # set when the core reports the link failed or halted
        self._writing = False  # a write of what the core hands out is under way
        self._group: asyncio.Task[None] | None = None

    # -- what the core knows ----------------------------------------------------------------

    @property
    def config(self) -> StreamerConfig:
        """The link's settings (with the firmware's defaults once connected)."""
        return self.core.config

    @property
    def profile(self) -> Profile | None:
        """The firmware defaults chosen at connect (None before)."""
        return self.core.handshake.profile

    @property
    def motion(self) -> PrinterMotion:
        """The motion settings ``M503`` reported at connect."""
        return self.core.handshake.motion

    @property
    def numbering_kept(self) -> bool | None:
        """After ``connect(probe_numbering=True)``: whether the printer still counted the
        lines of an earlier session (None: not probed, or no answer)."""
        return self.core.handshake.numbering_kept

    @property
    def numbering_last_line(self) -> int | None:
        """The printer's last line before the handshake, when probed."""
        return self.core.handshake.numbering_last_line

    @property
    def state(self) -> LinkState:
        """The link's state (a :class:`~drivers.link.events.LinkState`, equal to its name)."""
        return self.core.state

    @property
    def error(self) -> str | None:
        """Why the link failed or halted."""
        return self.core.error

    @property
    def stats(self) -> StreamStats:
        """Counters of what the link has done."""
        return self.core.stats

    @property
    def acked(self) -> int:
        """Job lines acknowledged so far."""
        return self.core.acked

    @property
    def firmware(self) -> str:
        """The ``FIRMWARE_NAME`` line of ``M115`` (empty until known)."""
        return self.core.firmware

    @property
    def capabilities(self) -> dict[str, str]:
        """``Cap:NAME:value`` lines of ``M115``."""
        return self.core.capabilities

    @property
    def capable(self) -> frozenset[str]:
        """Names of the capabilities the firmware reported as enabled (``Cap:NAME:1``)."""
        return self.core.capable

    @property
    def served(self) -> bool:
        """Whether received lines reach the core from the port's read callback
        (:meth:`Transport.serve`), the path without a task switch per line."""
        transport = self._transport
        return isinstance(transport, Transport) and transport.serving

    @property
    def in_flight(self) -> int:
        """Lines written and not yet acknowledged."""
        return len(self.core.window)

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
        if self._group is not None:
            await cancel_and_wait(self._group)
            self._group = None
        self._waiters.fail_all(LinkError("link closed"))
        self._tags.clear()
        self._progress.set()
        await self._transport.close()
        self.core.closed()

    # -- public API -----------------------------------------------------------------------

    async def connect(self, probe_numbering: bool = False) -> None:
        """The core's handshake (:mod:`drivers.link.handshake`): wait for ``start`` (or a
        timeout), a newline, then ``M110``, ``M115``, ``M503`` (the motion settings,
        :attr:`motion`; with ``read_motion``) and auto-report.

        ``probe_numbering``: first find out whether the printer still counts the lines
        of an earlier session (:mod:`drivers.link.numbering`; :attr:`numbering_kept`).
        Raises :class:`LinkError` if the printer does not answer in ``connect_timeout_s``.
        """
        self._start_tasks()
        core = self.core
        core.begin_connect(asyncio.get_running_loop().time(), probe_numbering=probe_numbering)
        self._wake.set()
        while not core.handshake.done:
            self._check_alive()
            self._progress.clear()
            await self._progress.wait()
        log_connection(core.handshake, core.config)

    @contextlib.contextmanager
    def acknowledgements(self, channel: AckChannel | None = None) -> Iterator[AckChannel]:
        """Attach ``channel`` (default: a new one) to receive every job line's :class:`Ack`
        until the block ends, then close it.

        One listener at a time (a job); acknowledgements with no listener are dropped.
        """
        if self._acks is not None:
            raise RuntimeError("a listener is already attached to the acknowledgements")
        channel = channel or AckChannel()
        self._acks = channel
        try:
            yield channel
        finally:
            self._acks = None
            channel.close()

    async def send(self, command: str, tag: Hashable | None = None) -> int:
        """Queue one job command; returns its line number once it has been written.

        ``tag`` comes back in the line's :class:`Ack` once the printer acknowledged it
        (say, the layer and the command's index in it). Waits while the send-ahead window
        is full or the stream is paused. Raises :class:`StreamCancelled` after
        ``cancel()``, :class:`LinkError` if the link failed.
        """
        command = command.strip()
        if not command:
            raise ValueError("empty command")
        core = self.core
        self._check_sendable()
        token, future = self._waiters.new()
        if tag is not None:
            self._tags.queued(token, tag)
        core.queue_job(command, token)
        return await self._written(future)

    async def send_many(self, commands: Iterable[tuple[str, Hashable | None]]) -> int | None:
        """Queue job commands, each with its tag (None: untagged), in one call; returns the
        last one's line number once it has been written (None when there were none).

        As :meth:`send` called for each in turn, but the caller waits once for all of
        them, not once per line (a layer's lines: no task switch and no future a line).
        The lines wait in the core until the window has room for them; ``cancel()``
        drops those not written and this raises :class:`StreamCancelled`.
        """
        core = self.core
        self._check_sendable()
        checked = []
        for command, tag in commands:
            command = command.strip()
            if not command:
                raise ValueError("empty command")
            checked.append((command, tag))
        if not checked:
            return None
        new_token, queued, queue_job = self._waiters.token, self._tags.queued, core.queue_job
        token = 0
        for command, tag in checked:
            token = new_token()
            if tag is not None:
                queued(token, tag)
            queue_job(command, token)
        return await self._written(self._waiters.wait_for(token))

    def _check_sendable(self) -> None:
        """Raise what a job line sent now would meet: a cancelled stream, a failed link,
        an emergency stop."""
        core = self.core
        if core.cancelled:
            raise StreamCancelled("stream cancelled")
        if not core.alive():
            raise LinkError(core.error or "link failed")
        if core.stopping:
            raise LinkError("emergency stop")

    async def _written(self, future: asyncio.Future[int]) -> int:
        """Write what the core lets go now, then wait for ``future`` (a line written).

        Written at once when the window has room (the future is then done and awaiting it
        does not suspend); otherwise the lines wait in the core for an ok to free room."""
        transport = self._transport
        if not self._writing and isinstance(transport, Transport):
            self._pump(transport, asyncio.get_running_loop().time())
        else:
            await self._write_ready()
        return await future

    async def drain(self) -> None:
        """Wait until every line written has been acknowledged (and a probe after them
        answered, which proves it whatever noise did to the oks)."""
        while not self.core.settled():
            self._check_alive()
            self._progress.clear()
            self._wake.set()
            await self._progress.wait()
        self._check_alive()

    async def pause(self, park: Iterable[str] | None = None, *, settle: bool = True) -> None:
        """Stop after the lines already written; then send the park G-code (if any).

        Returns once the printer has acknowledged everything sent (at once with
        ``settle=False``). ``park`` overrides ``config.park_gcode``.
        """
        self.core.pause(list(self.config.park_gcode if park is None else park))
        self._wake.set()
        if settle:
            await self.drain()

    async def resume(self, unpark: Iterable[str] | None = None) -> None:
        """Send the unpark G-code, then continue exactly where the stream stopped."""
        for command in self.config.unpark_gcode if unpark is None else unpark:
            await self._control_line(command, internal=False)
        self.core.resume()
        self._wake.set()

    async def cancel(self, end_gcode: Iterable[str] = (), *, settle: bool = True) -> None:
        """Refuse further job lines, send ``end_gcode`` after what is in flight, drain
        (not with ``settle=False``).

        Pending and later ``send()`` calls raise :class:`StreamCancelled` until
        ``begin_job()`` opens the link to the next job.
        """
        for token in self.core.cancel(list(end_gcode)):
            self._tags.dropped(token)
            self._waiters.settle(token, error=StreamCancelled("stream cancelled"))
        self._wake.set()
        if settle:
            await self.drain()
        self.core.cancel_done()

    def begin_job(self) -> None:
        """Accept job lines again after ``cancel()`` (the link itself stays connected)."""
        self.core.begin_job()
        self._wake.set()

    async def emergency_stop(self) -> None:
        """``M112`` at once: out of band with an emergency parser, else as the next line.

        Job lines not yet written fail at once (:class:`LinkError`), and none is written
        after the ``M112``. The link then waits for the printer to report its halt, up to
        ``KILL_REPLY_S`` (out of band) or ``KILL_QUEUED_S`` (behind the printer's queue),
        still answering its resend requests, so that an ``M112`` refused is sent again and
        the port is not closed before it has arrived. Without that report the user is told
        (``on_error``); the link is halted either way.
        """
        self._failed.clear()
        out_of_band, dropped = self.core.urgent("M112")
        wait = KILL_REPLY_S if out_of_band else KILL_QUEUED_S
        for token in dropped:
            self._tags.dropped(token)
            self._waiters.settle(token, error=LinkError("emergency stop"))
        if not out_of_band:
            await asyncio.sleep(0)
        await self._write_ready()
        if self.core.alive():
            try:
                async with asyncio.timeout(wait):
                    await self._failed.wait()
            except TimeoutError:
                self.core.report(f"the printer did not report its halt within {wait:g} s of "
                                 "the emergency stop (M112): it may still be moving")
        self.core.halt("emergency stop")
        self._dispatch(self.core.take_events())

    async def interrupt_wait(self) -> None:
        """``M108``: break out of a heating wait or user prompt (out of band when offered)."""
        await self._urgent("M108")

    async def quick_stop(self) -> None:
        """``M410``: stop all moves at once, keeping the printer alive."""
        await self._urgent("M410")

    # -- tasks --------------------------------------------------------------------------------

    def _start_tasks(self) -> None:
        if self._group is None:
            self._group = asyncio.create_task(self._run(), name="streamer")

    async def _run(self) -> None:
        try:
            async with asyncio.TaskGroup() as group:
                group.create_task(self._read_loop(), name="streamer-reader")
                group.create_task(self._write_loop(), name="streamer-writer")
                group.create_task(self._watch_loop(), name="streamer-watchdog")
        except Exception as exc:  # a bug in a task: the link must not hang silently
            self.core.fail(f"link task failed: {exc!r}")
            self._dispatch(self.core.take_events())

    async def _read_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            transport = self._transport
            try:
                if isinstance(transport, Transport):
                    await transport.serve(self._on_line)  # returns only by raising
                text = await transport.readline()
            except TransportError as exc:
                if not await self._link_lost(str(exc)):
                    return
                continue
            self._dispatch(self.core.feed(text, loop.time()), wake=False)
            # what the reply let go (the room an ok freed, a replay) is written at once,
            # not one loop iteration later by the writer task
            await self._write_ready()
            self._progress.set()

    def _on_line(self, text: str) -> None:
        """One line received, from the serial transport's read callback: fed to the core,
        and what it lets go written at once, with no task switch (the reader task only
        waits for the port to fail). Other transports are read by the reader task."""
        core = self.core
        now = asyncio.get_running_loop().time()
        events = core.feed(text, now)
        if events:
            self._dispatch(events, wake=False, progress=False)
        if self._writing:  # (a write suspended elsewhere: that writer asks again after it)
            self._wake.set()
        else:
            transport = self._transport
            assert isinstance(transport, Transport)
            self._pump(transport, now, progress=False)
        self._progress.set()

    def _pump(self, transport: Transport, now: float, *, progress: bool = True) -> None:
        """Write everything the core hands out now in one write, without suspending (the
        serial transport's ``write_now``): the lines an answer lets go leave in one
        system call, and what the core decided meanwhile is carried out once. A failed
        write is the reader task's to report (``serve()`` raises it)."""
        core = self.core
        next_bytes = core.next_bytes
        data = next_bytes(now)
        if data is None:
            events = core.take_events()
            if events:
                self._dispatch(events, wake=False, progress=progress)
            return
        more = next_bytes(now)
        if more is not None:
            chunks = [data, more]
            while (more := next_bytes(now)) is not None:
                chunks.append(more)
            data = b"".join(chunks)
        self._dispatch(core.take_events(), wake=False, progress=progress)
        try:  # noqa: SIM105 (contextlib.suppress: three Python calls a line more)
            transport.write_now(data)
        except TransportError:
            pass  # serve() raises it: the reader task reports the failure

    async def _write_loop(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            await self._write_ready()

    async def _write_ready(self) -> None:
        """Write every line the core hands out now.

        Called by the writer task when woken, and directly by ``send()`` and the reader
        (which saves a wake-up of the writer for each line). One writer at a time, so
        bytes go out in the order the core handed them out: while a write is under way
        (a transport whose write suspends) another caller returns at once, and the one
        writing asks the core again after each write, so it sees whatever changed.
        """
        if self._writing:
            return
        transport: object = self._transport  # (a wrapper's write may suspend)
        if isinstance(transport, Transport):  # its writes never suspend: all in one
            self._pump(transport, asyncio.get_running_loop().time())
            return
        self._writing = True
        try:
            core = self.core
            loop = asyncio.get_running_loop()
            while (data := core.next_bytes(loop.time())) is not None:
                self._dispatch(core.take_events(), wake=False)
                try:
                    await self._transport.write(data)
                except TransportError:
                    return  # the reader reports the failure
            self._dispatch(core.take_events(), wake=False)
        finally:
            self._writing = False

    async def _watch_loop(self) -> None:
        loop = asyncio.get_running_loop()
        interval = self.core.tick_interval()
        while True:
            await asyncio.sleep(interval)
            self._dispatch(self.core.tick(loop.time()))
            self._wake.set()
            self._progress.set()

    # -- waiters and events -------------------------------------------------------------------

    async def _control_line(self, command: str, internal: bool = True) -> int:
        token, waiter = self._waiters.new()
        self.core.queue_control(command, internal=internal, token=token)
        self._wake.set()
        return await waiter

    async def _urgent(self, command: str) -> None:
        self.core.urgent(command)
        await self._write_ready()

    def _dispatch(self, events: list[Event], *, wake: bool = True, progress: bool = True) -> None:
        """Carry out what the core decided; ``wake`` the writer task after (not needed
        when the caller is writing what the core hands out anyway); tell the waiters of
        progress (``progress``; the read callback does once per line)."""
        if not events:
            return
        for event in events:
            if isinstance(event, Written):
                self._tags.written(event.token, event.number)
                self._waiters.settle(event.token, result=event.number)
            elif isinstance(event, Acked):
                if event.job:
                    tag = self._tags.acked(event.number)
                    if self._acks is not None:
                        self._acks.put(Ack(event.number, event.command, tag))
                if event.token is not None:
                    self._waiters.settle(event.token, result=event.number)
            elif isinstance(event, Temperature):
                if self.on_temperature is not None:
                    self.on_temperature(event.response)
            elif isinstance(event, Report):
                if self.on_error is not None:
                    self.on_error(event.text)
            elif isinstance(event, Booted):
                if self.on_boot is not None:
                    self.on_boot()
            elif isinstance(event, Failed):
                self._tags.clear()
                self._waiters.fail_all(LinkError(event.reason))
                self._failed.set()
        if wake:
            self._wake.set()
        if progress:
            self._progress.set()

    async def _link_lost(self, reason: str) -> bool:
        """The port failed: report, then try to reopen it. True if the link is back."""
        self.core.link_lost(reason)
        self._dispatch(self.core.take_events())
        transport = await self._reconnector.again(self._transport, self.config)
        if transport is not None:
            self._transport = transport
            # the core writes a newline first: the end of whatever partial line the
            # printer kept from before the cut
            self.core.reopened(asyncio.get_running_loop().time())
            self._wake.set()
            return True
        self.core.fail(f"link lost: {reason}")
        self._dispatch(self.core.take_events())
        return False

    def _check_alive(self) -> None:
        if not self.core.alive():
            raise LinkError(self.core.error or "link failed")
