"""Whether a dropped file is still being written: writers found under /proc, and its
fingerprint (length and digest)."""

from __future__ import annotations

import asyncio
import hashlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

PROC = Path("/proc")


def open_for_writing(path: Path, proc: Path = PROC) -> bool:
    """True when a process holds ``path`` open for writing (Linux; False elsewhere).

    Every open file descriptor under ``/proc/<pid>/fd`` that leads to the same
    file (device and inode, so a rename does not hide it) and was opened
    write-only or read-write (``flags`` in ``/proc/<pid>/fdinfo/<fd>``) counts.
    Only processes this one may inspect are seen: those of the same user, or
    all of them when running as root.
    """
    try:
        target = os.stat(path)
    except OSError:
        return False
    wanted = (target.st_dev, target.st_ino)
    try:
        pids = [name for name in os.listdir(proc) if name.isdigit()]
    except OSError:
        return False
    for pid in pids:
        fd_dir = proc / pid / "fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:  # gone, or not ours to look at
            continue
        for fd in fds:
            try:
                info = os.stat(fd_dir / fd)
            except OSError:
                continue
            if (info.st_dev, info.st_ino) == wanted and _writable(proc / pid / "fdinfo" / fd):
                return True
    return False


def _writable(fdinfo: Path) -> bool:
    """True when the descriptor described by ``fdinfo`` was opened for writing."""
    try:
        text = fdinfo.read_text(encoding="ascii", errors="replace")
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("flags:"):
            flags = int(line.split()[1], 8)
            return flags & os.O_ACCMODE in (os.O_WRONLY, os.O_RDWR)
    return False


@dataclass(frozen=True)
class Fingerprint:
    """What a file held when it was read: its length and the SHA-256 of those bytes."""

    size: int
    sha256: str

    def still(self, path: Path) -> bool:
        """True when ``path`` still has the length read (a write since that changed it
        shows; the hash read again tells the rest)."""
        try:
            return path.stat().st_size == self.size
        except OSError:
            return False


def fingerprint(path: Path) -> Fingerprint:
    """The length and SHA-256 of a file's bytes, read once (the length is of the bytes
    hashed, not of a stat that a writer may have moved on since)."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
            size += len(block)
    return Fingerprint(size, digest.hexdigest())


def sha256_of(path: Path) -> str:
    """The SHA-256 of a file's bytes, as hex."""
    return fingerprint(path).sha256


def _signature(path: Path) -> tuple[int, int] | None:
    try:
        info = path.stat()
    except OSError:
        return None
    return (info.st_size, info.st_mtime_ns)


async def wait_complete(path: Path, settle_s: float, poll_s: float = 0.05) -> None:
    """Return once no process writes ``path`` and its size and mtime held for ``settle_s``."""
    last = _signature(path)
    since = time.monotonic()
    while True:
        await asyncio.sleep(poll_s)
        now = _signature(path)
        if now != last:
            last, since = now, time.monotonic()
            continue
        if time.monotonic() - since >= settle_s and not await asyncio.to_thread(
            open_for_writing, path
        ):
            return
