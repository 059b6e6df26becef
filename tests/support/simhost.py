"""A minimal test host for the simulated printer: raw pty I/O plus a one-line-in-flight sender."""

from __future__ import annotations

import contextlib
import os
import re
import select
import termios
import time
import tty
from collections.abc import Callable

from drivers.link.protocol import frame
from support.waiting import wait_until

_RESEND = re.compile(r"(?:Resend|rs):?\s*(\d+)")
_LAST_LINE = re.compile(r"Last Line: (\d+)")
_BANNER = ("start", "echo:Marlin 2.1.2 (hostd simulator)")


class PortGone(Exception):
    """The device vanished or hung up."""


class Host:
    """Opens the printer's device and exchanges whole lines with it."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        termios.tcflush(self.fd, termios.TCIFLUSH)
        self._buffer = b""
        self.received: list[str] = []

    def reopen(self, timeout: float = 5.0, hung_up: Callable[[], bool] | None = None) -> None:
        """Close and open the device path again, waiting for it to come back.

        ``hung_up``: true once the printer saw the port closed (its reset needs it); a
        port that vanished has no one to tell.
        """
        self.close()
        if hung_up is not None:
            wait_until(hung_up, timeout, "the printer to see the port closed")
        self._buffer = b""
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.fd = os.open(self.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.02)
        tty.setraw(self.fd)
        termios.tcflush(self.fd, termios.TCIFLUSH)

    def close(self) -> None:
        """Close the device."""
        if self.fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = -1

    def write(self, data: bytes) -> None:
        """Write every byte of ``data``."""
        view = memoryview(data)
        while view:
            try:
                sent = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
                continue
            except OSError as exc:
                raise PortGone(str(exc)) from exc
            view = view[sent:]

    def send(self, number: int, command: str) -> None:
        """Write one framed line."""
        self.write(frame(number, command))

    def readline(self, timeout: float = 2.0) -> str | None:
        """The next line without its terminator, or None after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self.fd], [], [], left)
            if not ready:
                return None
            try:
                chunk = os.read(self.fd, 4096)
            except BlockingIOError:
                continue
            except OSError as exc:
                raise PortGone(str(exc)) from exc
            if not chunk:
                raise PortGone("end of file")
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        text = line.decode("latin-1").rstrip("\r")
        self.received.append(text)
        return text

    def read_until(self, predicate, timeout: float = 5.0) -> list[str]:
        """Lines up to and including the first that satisfies ``predicate``."""
        deadline = time.monotonic() + timeout
        lines: list[str] = []
        while True:
            line = self.readline(max(0.0, deadline - time.monotonic()))
            if line is None:
                raise TimeoutError(f"no matching line; got {lines[-10:]}")
            lines.append(line)
            if predicate(line):
                return lines

    def wait_start(self, timeout: float = 5.0) -> list[str]:
        """Wait for the ``start`` banner."""
        return self.read_until(lambda line: line == "start", timeout)

    def command(self, number: int, command: str, timeout: float = 5.0) -> list[str]:
        """Send one framed line and read up to its ``ok``."""
        self.send(number, command)
        return self.read_until(lambda line: line.startswith("ok"), timeout)


def resync(host: Host, last: int, timeout: float = 0.2) -> None:
    """Make the printer's last line number ``last`` (``M110``), retrying until it is taken."""
    while True:
        clean = True
        deadline = time.monotonic() + timeout
        try:
            host.send(0, f"M110 N{last}")
        except PortGone:
            _reconnect(host, last)
            continue
        while True:
            try:
                line = host.readline(max(0.0, deadline - time.monotonic()))
            except PortGone:
                _reconnect(host, last)
                break
            if line is None:
                break
            if line == "start" or line.startswith("Error") or _RESEND.match(line):
                clean = False
            elif line.startswith("ok"):
                if clean:
                    return
                break


def stream(host: Host, commands: list[str], ok_timeout: float = 0.2) -> int:
    """Send ``commands`` one line in flight, recovering from every fault; returns rounds.

    Lines ``1..n-1`` are known executed. Recovery rests on the firmware's line numbers: a
    line that may or may not have been executed is sent again, and a firmware that already
    has it answers with a line-number error naming it as its last line. A resend request
    is obeyed only when it agrees with the error before it; the boot banner means a reset:
    renumber and go on.
    """
    resync(host, 0)
    n = 1
    rounds = 0
    while n <= len(commands):
        rounds += 1
        try:
            host.send(n, commands[n - 1])
        except PortGone:
            _reconnect(host, n)
            continue
        target: int | None = None
        last: int | None = None
        trouble = restarted = acked = False
        deadline = time.monotonic() + ok_timeout
        while True:
            try:
                line = host.readline(max(0.0, deadline - time.monotonic()))
            except PortGone:
                line = None
                restarted = True
                _reconnect(host, n)
                break
            if line is None:
                break
            if line in _BANNER:
                restarted = True
                break
            if line.startswith("echo:busy") or line.startswith(" T:"):
                deadline = time.monotonic() + ok_timeout
                continue
            if line.startswith("Error:"):
                trouble = True
                found = _LAST_LINE.search(line)
                last = int(found.group(1)) if found else None
            elif "Unknown command" in line:
                trouble = True
            match = _RESEND.match(line)
            if match:
                target = int(match.group(1))
            elif line.startswith("ok"):
                acked = True
                break
        if restarted:
            with contextlib.suppress(TimeoutError):
                host.read_until(lambda x: x.startswith("echo: Free"), 0.5)
            resync(host, n - 1)
        elif last is not None and target == last + 1:
            if last == n:
                n += 1  # the firmware already has line n
            elif last < n:
                n = last + 1
        elif acked and not trouble and target is None:
            n += 1
    return rounds


def _reconnect(host: Host, n: int) -> None:
    """The port vanished: open it again and wait for the reset it causes."""
    host.reopen()
    with contextlib.suppress(TimeoutError):
        host.read_until(lambda x: x in _BANNER, 2.0)
