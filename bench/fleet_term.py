"""A command in a pseudo-terminal of a set size, its output read and dropped (a real TTY)."""

from __future__ import annotations

import fcntl
import os
import signal
import struct
import subprocess
import termios
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

TRUECOLOUR = {"TERM": "xterm-256color", "COLORTERM": "truecolor"}
COLOUR_256 = {"TERM": "xterm-256color"}
COLOUR_VARIABLES = ("TERM", "COLORTERM", "NO_COLOR", "TEXTUAL_COLOR_SYSTEM")


class Terminal:
    """Runs ``command`` on a fresh pseudo-terminal of ``columns`` x ``rows``.

    ``term`` sets the terminal's variables (``TERM``, ``COLORTERM``...; any of
    them not given is unset). Every read is kept in :attr:`chunks` as
    (``time.monotonic()``, bytes), so a caller can count what the command wrote
    in any window.
    """

    def __init__(self, command: Sequence[str], *, cwd: Path, env: Mapping[str, str],
                 columns: int = 160, rows: int = 48,
                 term: Mapping[str, str] = TRUECOLOUR) -> None:
        self.master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
        plain = {k: v for k, v in env.items() if k not in COLOUR_VARIABLES}
        self.proc = subprocess.Popen(
            list(command), stdin=slave, stdout=slave, stderr=slave, cwd=cwd,
            env={**plain, **term}, start_new_session=True,
        )
        os.close(slave)
        self.bytes_out = 0
        self.chunks: list[tuple[float, int]] = []
        self.tail = b""  # the last output, to tell why the command ended
        self._reader = threading.Thread(target=self._drain, name="pty-drain", daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int:
        """The command's process id."""
        return self.proc.pid

    def _drain(self) -> None:
        while True:
            try:
                data = os.read(self.master, 1 << 16)
            except OSError:
                return
            if not data:
                return
            self.bytes_out += len(data)
            self.chunks.append((time.monotonic(), len(data)))
            self.tail = (self.tail + data)[-4096:]

    def bytes_between(self, start: float, stop: float) -> int:
        """Bytes read from ``start`` (included) to ``stop`` (excluded), monotonic seconds."""
        return sum(n for t, n in list(self.chunks) if start <= t < stop)

    def close(self) -> None:
        """Stop the command (SIGTERM, then SIGKILL after 10 s) and close the terminal."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        os.close(self.master)
