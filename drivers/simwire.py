"""The simulated printer's serial line: a pseudo-terminal served by one I/O thread.

The thread reads the host's bytes from the master side at the wire's speed and hands them
to the firmware (the "UART interrupt"), writes the firmware's output at the wire's speed,
notices when the host opens or closes the port, and can make the port vanish.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import select
import threading
import time
import tty
from collections.abc import Callable

_CLOSED_PROBE_S = 0.01  # how often a port nobody has open is checked for an opener
_READ_CHUNK = 4096


class _Pacer:
    """Token bucket of a wire direction: ``rate`` bytes/s, small bursts; 0 = unlimited."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self.burst = max(16.0, rate * 0.004)
        self.tokens = self.burst
        self.stamp = time.monotonic()

    def available(self, now: float) -> int:
        """Bytes that may cross the wire now."""
        if self.rate <= 0.0:
            return _READ_CHUNK
        self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
        self.stamp = now
        return int(self.tokens)

    def consume(self, count: int) -> None:
        """Account for ``count`` bytes sent or received."""
        if self.rate > 0.0:
            self.tokens -= count

    def delay(self) -> float:
        """Seconds until at least one byte may cross."""
        if self.rate <= 0.0 or self.tokens >= 1.0:
            return 0.0
        return (1.0 - self.tokens) / self.rate


class PtyWire:
    """One pseudo-terminal and the thread that moves bytes across it.

    ``receive(data)`` is called from the I/O thread with each chunk read from the host;
    ``opened()`` each time the host opens the port (the first time included).
    """

    def __init__(
        self,
        bytes_per_second: float,
        receive: Callable[[bytes], None],
        opened: Callable[[], None],
        link_path: str | None = None,
        reconnect_delay_s: float = 0.2,
    ) -> None:
        self._rate = bytes_per_second
        self._receive = receive
        self._opened = opened
        self._link_path = link_path
        self._reconnect_delay_s = reconnect_delay_s
        self._lock = threading.Lock()
        self._tx_empty = threading.Condition(self._lock)
        self._tx = bytearray()
        self._stop = threading.Event()
        self._vanish_requested = False
        self._master = -1
        self._path = ""
        self._connected = False
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = os.pipe()
        for fd in (self._wake_r, self._wake_w):
            os.set_blocking(fd, False)
        self.bytes_in = 0
        self.bytes_out = 0

    @property
    def path(self) -> str:
        """Device path of the current pseudo-terminal (changes after a disconnect)."""
        return self._path

    @property
    def connected(self) -> bool:
        """True while the host has the port open."""
        return self._connected

    def open(self) -> str:
        """Create the pseudo-terminal, start the I/O thread; returns the device path."""
        self._open_pty()
        self._thread = threading.Thread(target=self._serve, name="sim-wire", daemon=True)
        self._thread.start()
        return self._path

    def send(self, data: bytes) -> None:
        """Queue ``data`` for the host (thread-safe); dropped while nobody has the port open."""
        with self._lock:
            if not self._connected:
                return
            was_empty = not self._tx
            self._tx += data
        if was_empty:
            self._wake()

    def wait_sent(self, timeout: float) -> bool:
        """Wait until every queued byte has been written (or the port is closed)."""
        deadline = time.monotonic() + timeout
        with self._tx_empty:
            while self._tx and not self._stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0.0:
                    return False
                self._tx_empty.wait(left)
        return True

    def vanish(self) -> None:
        """Close the pseudo-terminal as an unplugged USB cable would.

        With a link path, a new pseudo-terminal appears after the reconnect delay and the
        link is pointed at it.
        """
        with self._lock:
            self._vanish_requested = True
        self._wake()

    def close(self) -> None:
        """Stop the thread and close every descriptor; idempotent."""
        self._stop.set()
        self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._thread = None
        self._close_master()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_r = self._wake_w = -1
        if self._link_path:
            with contextlib.suppress(OSError):
                os.unlink(self._link_path)

    # --- I/O thread -----------------------------------------------------------------

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        self._path = os.ttyname(slave)
        os.close(slave)  # the host's open is then seen as the end of the hang-up
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self._master = master
        if self._link_path:
            tmp = f"{self._link_path}.{os.getpid()}.tmp"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self._path, tmp)
            os.replace(tmp, self._link_path)

    def _close_master(self) -> None:
        with self._lock:
            self._connected = False
            self._tx.clear()
            self._tx_empty.notify_all()
        if self._master >= 0:
            with contextlib.suppress(OSError):
                os.close(self._master)
            self._master = -1

    def _serve(self) -> None:
        rx = _Pacer(self._rate)
        tx = _Pacer(self._rate)
        reopen_at: float | None = None
        while not self._stop.is_set():
            if self._vanish_requested:
                with self._lock:
                    self._vanish_requested = False
                if self._link_path:  # first the name goes, then the device
                    with contextlib.suppress(OSError):
                        os.unlink(self._link_path)
                    reopen_at = time.monotonic() + self._reconnect_delay_s
                self._close_master()
                continue
            if self._master < 0:
                timeout = None if reopen_at is None else max(0.0, reopen_at - time.monotonic())
                self._wait_wake(timeout)
                if reopen_at is not None and time.monotonic() >= reopen_at:
                    reopen_at = None
                    self._open_pty()
                continue
            if not self._connected:
                self._wait_for_opener()
                continue
            self._pump(rx, tx)

    def _wait_wake(self, timeout: float | None) -> None:
        ready, _, _ = select.select([self._wake_r], [], [], timeout)
        if ready:
            self._drain_wake()

    def _drain_wake(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.read(self._wake_r, 4096)

    def _wait_for_opener(self) -> None:
        probe = select.poll()
        probe.register(self._master, select.POLLIN)
        if any(ev & select.POLLHUP for _, ev in probe.poll(0)):
            self._wait_wake(_CLOSED_PROBE_S)
            return
        with self._lock:
            self._connected = True
        self._opened()

    def _pump(self, rx: _Pacer, tx: _Pacer) -> None:
        now = time.monotonic()
        can_read = rx.available(now) >= 1
        with self._lock:
            pending = bool(self._tx)
        can_write = pending and tx.available(now) >= 1
        events = (select.POLLIN if can_read else 0) | (select.POLLOUT if can_write else 0)
        poller = select.poll()
        poller.register(self._wake_r, select.POLLIN)
        poller.register(self._master, events)
        delays = [d for d in (rx.delay() if not can_read else 0.0,
                              tx.delay() if pending and not can_write else 0.0) if d > 0.0]
        timeout_ms = None if not delays else max(1.0, min(delays) * 1000.0)
        for fd, ev in poller.poll(timeout_ms):
            if fd == self._wake_r:
                self._drain_wake()
                continue
            if ev & (select.POLLHUP | select.POLLERR):
                self._hang_up()  # the host closed the port; what it wrote last is lost
                return
            if ev & select.POLLIN and can_read:
                self._read(rx)
            if ev & select.POLLOUT and can_write:
                self._write(tx)

    def _read(self, rx: _Pacer) -> None:
        try:
            data = os.read(self._master, min(_READ_CHUNK, rx.available(time.monotonic())))
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._hang_up()
                return
            raise
        if not data:
            self._hang_up()
            return
        rx.consume(len(data))
        self.bytes_in += len(data)
        self._receive(data)

    def _write(self, tx: _Pacer) -> None:
        with self._lock:
            budget = min(len(self._tx), tx.available(time.monotonic()))
            chunk = bytes(self._tx[:budget])
        try:
            written = os.write(self._master, chunk)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._hang_up()
                return
            raise
        tx.consume(written)
        self.bytes_out += written
        with self._lock:
            del self._tx[:written]
            if not self._tx:
                self._tx_empty.notify_all()

    def _hang_up(self) -> None:
        with self._lock:
            self._connected = False
            self._tx.clear()
            self._tx_empty.notify_all()
