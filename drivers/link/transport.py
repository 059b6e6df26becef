"""Serial transport: pyserial driven from asyncio without ever blocking the event loop."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import termios
from collections import deque
from collections.abc import Callable
from types import TracebackType

import serial

from drivers.link.errors import TransportError

_READ_CHUNK = 4096


class Transport:
    """A byte pipe to the printer: write bytes, read lines.

    Built by :func:`open_transport`. The port's file descriptor is watched by the event
    loop (``add_reader``/``add_writer``) in non-blocking mode, so neither reads nor writes
    ever block the loop. A read error, end of file (port unplugged, pseudo-terminal
    closed) or a write error ends the transport: pending and later ``readline()`` calls
    raise :class:`TransportError`.
    """

    def __init__(self, port: serial.SerialBase, loop: asyncio.AbstractEventLoop) -> None:
        self._port = port
        self._loop = loop
        self._fd = port.fileno()
        self._lines: deque[str] = deque()  # received, not yet read
        self._readers: list[asyncio.Future[None]] = []  # readline() calls waiting for a line
        self._ended = False  # closed or failed: once the lines received are read, it raises
        self._partial = bytearray()
        self._out = bytearray()
        self._writing = False
        self._error: TransportError | None = None
        self._closed = False
        self._serving: Callable[[str], None] | None = None  # serve()'s reader
        self._served: asyncio.Future[None] | None = None  # ends serve()
        self.bytes_written = 0
        self.bytes_read = 0
        loop.add_reader(self._fd, self._on_readable)

    @property
    def name(self) -> str:
        """The port this transport was opened on."""
        return str(self._port.port)

    @property
    def baud(self) -> int:
        """The speed the port was opened at (bits per second)."""
        return int(getattr(self._port, "baudrate", 250000))

    @property
    def serving(self) -> bool:
        """True while :meth:`serve` hands the lines received to its reader."""
        return self._serving is not None

    @property
    def is_open(self) -> bool:
        """False once closed or failed."""
        return not self._closed and self._error is None

    async def write(self, data: bytes) -> None:
        """Queue ``data`` for the wire, in order; returns at once (never waits for the UART)."""
        self.write_now(data)

    def write_now(self, data: bytes) -> None:
        """:meth:`write` from a callback: the same, without a coroutine."""
        if self._error is not None:
            raise self._error
        if self._closed:
            raise TransportError(f"{self.name}: transport closed")
        self._out += data
        self.bytes_written += len(data)
        self._flush()

    async def readline(self) -> str:
        """The next line received, without its line ending (``\\r`` stripped too).

        Lines received before the transport closed or failed are still returned; then it
        raises :class:`TransportError`. A line already received is returned without
        suspending.
        """
        lines = self._lines
        while not lines:
            if self._ended:
                raise self._error or TransportError(f"{self.name}: transport closed")
            waiter = self._loop.create_future()
            self._readers.append(waiter)
            try:
                await waiter
            finally:
                if waiter in self._readers:  # cancelled: no longer waiting
                    self._readers.remove(waiter)
        return lines.popleft()

    async def serve(self, on_line: Callable[[str], None]) -> None:
        """Hand every line received to ``on_line`` (those already received first), from
        the event loop's read callback as each arrives, until the transport ends; then
        raise :class:`TransportError` (or what ``on_line`` raised).

        A reader that acts on each line at once saves the task switch per line that
        :meth:`readline` costs. One server at a time, and no ``readline()`` meanwhile.
        """
        served = self._served = self._loop.create_future()
        self._serving = on_line
        try:
            lines = self._lines
            while lines:
                on_line(lines.popleft())
            if self._ended:
                raise self._error or TransportError(f"{self.name}: transport closed")
            await served
        finally:
            self._serving = None
            self._served = None

    async def close(self) -> None:
        """Stop watching the port and close it; pending ``readline()`` calls fail."""
        if self._closed:
            return
        self._closed = True
        self._detach()
        with contextlib.suppress(OSError, serial.SerialException):
            self._port.close()
        self._end()

    async def __aenter__(self) -> Transport:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    # -- event-loop callbacks -------------------------------------------------------------

    def _on_readable(self) -> None:
        try:
            data = os.read(self._fd, _READ_CHUNK)
        except BlockingIOError:
            return
        except OSError as exc:
            self._fail(TransportError(f"{self.name}: read failed: {exc.strerror or exc}"))
            return
        if not data:
            self._fail(TransportError(f"{self.name}: port closed by the other end"))
            return
        self.bytes_read += len(data)
        partial = self._partial
        partial += data
        if b"\n" not in data:
            return
        *complete, rest = partial.split(b"\n")
        partial[:] = rest
        self._lines.extend(raw.decode("ascii", "replace").rstrip("\r") for raw in complete)
        if self._serving is not None:
            self._serve_lines(self._serving)
            return
        self._wake_readers()

    def _serve_lines(self, on_line: Callable[[str], None]) -> None:
        lines = self._lines
        try:
            while lines:
                on_line(lines.popleft())
        except Exception as exc:  # the server's failure ends serve(), not the event loop
            served = self._served
            if served is not None and not served.done():
                served.set_exception(exc)

    def _wake_readers(self) -> None:
        readers, self._readers = self._readers, []
        for waiter in readers:
            if not waiter.done():
                waiter.set_result(None)

    def _flush(self) -> None:
        while self._out:
            try:
                sent = os.write(self._fd, self._out)
            except BlockingIOError:
                sent = 0
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EINTR):
                    sent = 0
                else:
                    self._fail(TransportError(f"{self.name}: write failed: {exc.strerror}"))
                    return
            if sent == 0:
                if not self._writing:
                    self._writing = True
                    self._loop.add_writer(self._fd, self._on_writable)
                return
            del self._out[:sent]
        if self._writing:
            self._writing = False
            self._loop.remove_writer(self._fd)

    def _on_writable(self) -> None:
        self._flush()

    def _fail(self, error: TransportError) -> None:
        if self._error is not None or self._closed:
            return
        self._error = error
        self._detach()
        with contextlib.suppress(OSError, serial.SerialException):
            self._port.close()
        self._end()

    def _end(self) -> None:
        self._ended = True
        self._wake_readers()
        served = self._served
        if served is not None and not served.done():
            served.set_exception(self._error or TransportError(f"{self.name}: transport closed"))

    def _detach(self) -> None:
        with contextlib.suppress(ValueError, OSError):
            self._loop.remove_reader(self._fd)
        if self._writing:
            self._writing = False
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_writer(self._fd)


async def open_transport(port: str, baud: int = 250000) -> Transport:
    """Open ``port`` (a device path, pseudo-terminal path or pyserial URL) at ``baud``.

    Opening asserts DTR, which resets many 8-bit boards: the caller waits for ``start``.
    Raises :class:`TransportError` if the port cannot be opened or has no file descriptor.
    """
    loop = asyncio.get_running_loop()

    def _open() -> serial.SerialBase:
        return serial.serial_for_url(port, baudrate=baud, timeout=0, write_timeout=0)

    try:
        handle = await loop.run_in_executor(None, _open)
    except (serial.SerialException, OSError, ValueError, termios.error) as exc:
        # (termios.error, no OSError: a pseudo-terminal whose other end closed while
        # pyserial set it up; it failed the reconnecting link's task instead of an attempt)
        raise TransportError(f"{port}: cannot open: {exc}") from exc
    try:
        handle.fileno()
    except (AttributeError, NotImplementedError, serial.SerialException) as exc:
        handle.close()
        raise TransportError(f"{port}: not a file-descriptor port") from exc
    return Transport(handle, loop)
