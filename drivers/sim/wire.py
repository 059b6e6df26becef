"""The simulated printer's serial line: a pseudo-terminal served by one I/O thread.

The thread reads the host's bytes from the master side and hands them to the firmware
(the "UART interrupt") once they have crossed the wire, writes the firmware's output to
the host the same way, notices when the host opens or closes the port, and can make the
port vanish. Each direction keeps a queue of ``(deliver_at, bytes)``: a byte is delivered
after its wire time (ten bits at the baud rate, behind the bytes before it) plus the
link's one-way latency.
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
from collections import deque
from collections.abc import Callable

_CLOSED_PROBE_S = 0.01  # how often a port nobody has open is checked for an opener
_READ_CHUNK = 4096
_TICK_S = 0.001  # wire time of the pieces bytes are handed over in


class _Lane:
    """One direction of the wire: bytes in flight, each piece with the time it is delivered.

    A byte takes ``1 / rate`` seconds on the wire (bytes queue behind each other), then
    ``latency`` more (USB frames, the firmware's loop) before it reaches the other side.
    Bytes are handed over in pieces of at most one tick of wire time, each when its last
    byte has arrived, so no byte is ever delivered ahead of its wire time. ``rate`` 0
    means an unlimited wire: only the latency delays the bytes.
    """

    def __init__(self, rate: float, latency: float) -> None:
        self.rate = rate
        self.latency = latency
        self.piece = max(1, int(rate * _TICK_S)) if rate > 0.0 else _READ_CHUNK
        self.free_at = 0.0  # when the wire has carried every byte given to it so far
        self.queue: deque[tuple[float, bytes]] = deque()  # (deliver_at, bytes), in order

    def put(self, data: bytes, now: float) -> None:
        """Put ``data`` on the wire at ``now`` (behind any bytes still crossing it)."""
        if self.rate <= 0.0:
            self.queue.append((now + self.latency, data))
            return
        start = max(now, self.free_at)
        for first in range(0, len(data), self.piece):
            last = min(len(data), first + self.piece)
            self.queue.append((start + last / self.rate + self.latency, data[first:last]))
        self.free_at = start + len(data) / self.rate

    def due(self) -> float | None:
        """When the next piece is delivered; None when nothing is in flight."""
        return self.queue[0][0] if self.queue else None

    def take_due(self, now: float) -> bytes:
        """Every byte whose delivery time has come, removed from the lane."""
        out = bytearray()
        while self.queue and self.queue[0][0] <= now:
            out += self.queue.popleft()[1]
        return bytes(out)

    def put_back(self, data: bytes, now: float) -> None:
        """Return bytes the other side could not take yet; they are due at once."""
        self.queue.appendleft((now, data))

    def read_budget(self, now: float) -> int:
        """Bytes the wire can take now without a byte waiting more than two ticks."""
        if self.rate <= 0.0:
            return _READ_CHUNK
        room = now + 2.0 * _TICK_S - max(now, self.free_at)
        return max(1, min(_READ_CHUNK, int(room * self.rate)))

    def clear(self) -> None:
        """Forget every byte in flight (the port closed)."""
        self.queue.clear()
        self.free_at = 0.0


class PtyWire:
    """One pseudo-terminal and the thread that moves bytes across it.

    ``receive(data)`` is called from the I/O thread with each piece of the host's bytes
    once it has crossed the wire; ``opened()`` each time the host opens the port (the
    first time included). ``latency_s`` is added to every byte in each direction.

    The thread waits with ``select`` rather than ``poll``: poll's timeout is whole
    milliseconds, which would make deliveries up to a millisecond late, as much as the
    latency being modelled.
    """

    def __init__(
        self,
        bytes_per_second: float,
        receive: Callable[[bytes], None],
        opened: Callable[[], None],
        link_path: str | None = None,
        reconnect_delay_s: float = 0.2,
        latency_s: float = 0.0,
    ) -> None:
        self._rate = bytes_per_second
        self._latency_s = latency_s
        self._receive = receive
        self._opened = opened
        self._link_path = link_path
        self._reconnect_delay_s = reconnect_delay_s
        self._lock = threading.Lock()
        self._tx_empty = threading.Condition(self._lock)
        self._rx = _Lane(bytes_per_second, latency_s)  # host -> printer: I/O thread only
        self._tx = _Lane(bytes_per_second, latency_s)  # printer -> host: under the lock
        self._tx_writing = False  # bytes taken from the tx lane and not yet written
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
            if not self._connected or not data:
                return
            was_empty = not self._tx.queue
            self._tx.put(data, time.monotonic())
        if was_empty:
            self._wake()

    def wait_sent(self, timeout: float) -> bool:
        """Wait until every queued byte has been written (or the port is closed)."""
        deadline = time.monotonic() + timeout
        with self._tx_empty:
            while (self._tx.queue or self._tx_writing) and not self._stop.is_set():
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
        self._hang_up()
        if self._master >= 0:
            with contextlib.suppress(OSError):
                os.close(self._master)
            self._master = -1

    def _serve(self) -> None:
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
            self._pump()

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

    def _pump(self) -> None:
        """One round: deliver what is due, wait for the next event, read or write."""
        now = time.monotonic()
        arrived = self._rx.take_due(now)
        if arrived:
            self.bytes_in += len(arrived)
            self._receive(arrived)
            if not self._connected:
                return
        # read the host's bytes only when the wire is about to be free, so the host
        # feels the wire's pace the way it would on a real port
        can_read = self._rx.free_at - now < _TICK_S
        with self._lock:
            tx_due = self._tx.due()
        can_write = tx_due is not None and tx_due <= now
        deadlines = [t for t in (self._rx.due(), None if can_write else tx_due) if t is not None]
        if not can_read:
            deadlines.append(self._rx.free_at - _TICK_S)
        timeout = max(0.0, min(deadlines) - now) if deadlines else None
        readers = [self._wake_r, self._master] if can_read else [self._wake_r]
        writers = [self._master] if can_write else []
        try:
            readable, writable, _ = select.select(readers, writers, [], timeout)
        except OSError:  # the descriptor went away under us
            self._hang_up()
            return
        if self._wake_r in readable:
            self._drain_wake()
        if self._master in readable:
            self._read()
        if self._master in writable and self._connected:
            self._write()

    def _read(self) -> None:
        now = time.monotonic()
        try:
            data = os.read(self._master, self._rx.read_budget(now))
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._hang_up()  # the host closed the port; what it wrote last is lost
                return
            raise
        if not data:
            self._hang_up()
            return
        self._rx.put(data, now)

    def _write(self) -> None:
        with self._lock:
            chunk = self._tx.take_due(time.monotonic())
            self._tx_writing = bool(chunk)
        if not chunk:
            return
        try:
            written = os.write(self._master, chunk)
        except BlockingIOError:
            written = 0
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._hang_up()
                return
            raise
        self.bytes_out += written
        with self._lock:
            self._tx_writing = False
            if written < len(chunk):
                self._tx.put_back(chunk[written:], time.monotonic())
            if not self._tx.queue:
                self._tx_empty.notify_all()

    def _hang_up(self) -> None:
        with self._lock:
            self._connected = False
            self._tx.clear()
            self._tx_writing = False
            self._tx_empty.notify_all()
        self._rx.clear()
