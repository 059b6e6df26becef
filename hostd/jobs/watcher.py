"""The job folder watcher: an initial scan plus watchfiles, taking files once they settle."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path

from watchfiles import awatch

from hostd.jobs.filecheck import open_for_writing
from hostd.jobs.jobfolder import is_job_name

log = logging.getLogger("hostd.jobs.watcher")

OnSettled = Callable[[Path], Awaitable[None]]

# Linux's CLOCK_REALTIME_COARSE (not in the time module), which file times are taken from
_REALTIME_COARSE = 5


def _stamp_grain() -> float:
    """How far a file's change time may lag the moment of the change: one tick of the
    kernel's coarse clock (its resolution: 4 ms at 250 Hz), 10 ms where unknown."""
    try:
        tick = time.clock_getres(_REALTIME_COARSE) if sys.platform == "linux" else 0.0
    except OSError:
        tick = 0.0
    return tick if 0.0 < tick <= 0.01 else 0.01


_STAMP_GRAIN_S = _stamp_grain()
# how often a settled file that a writer still holds open is looked at again (s)
_HELD_RECHECK_S = 0.25


@dataclass(frozen=True)
class _Seen:
    """What a candidate looked like when last checked, and since when (monotonic s)."""

    signature: tuple[int, int, int, int] | None
    since: float


class Watcher:
    """Calls ``on_settled(path)`` once for each job file whose size and mtime held still.

    Only the top level of ``folder`` is watched (``done/`` and ``failed/`` live
    inside it). A file is settled when its size and modification time were the
    same for ``settle_s`` seconds and no process holds it open for writing (a copy
    that stalls longer than ``settle_s`` is waited for). Directories and links with
    job names are passed on too, so that the intake can refuse them with a reason.
    The folder is scanned again every ``rescan_s`` seconds in case an event was missed.
    ``on_still(path)`` is called when a file has held still for half its settle time
    (again after each change), so that work on it may begin before it is taken;
    ``on_seen(path)`` when a job name first appears (it must return at once).
    """

    def __init__(
        self, folder: Path, settle_s: float, on_settled: OnSettled, rescan_s: float = 10.0,
        on_still: Callable[[Path], None] | None = None,
        on_seen: Callable[[Path], None] | None = None,
    ) -> None:
        self.folder = folder
        self.settle_s = settle_s
        self.on_settled = on_settled
        self.on_still = on_still  # a file held still for half its settle time
        self.on_seen = on_seen  # a job name newly seen
        self.rescan_s = rescan_s
        self._pending: dict[Path, _Seen] = {}
        self._held: set[Path] = set()  # settled files a writer still holds open (logged once)
        # a look for writers begun while a file settles, with the signature it began at:
        # the look (a walk of /proc) is then off the path from settled to taken
        self._looks: dict[Path, tuple[tuple[int, int, int, int] | None, asyncio.Future[bool]]] = {}
        self._wake = asyncio.Event()

    async def run(self, stop: asyncio.Event | None = None) -> None:
        """Scan, then watch until cancelled or ``stop`` is set."""
        self.folder.mkdir(parents=True, exist_ok=True)
        stop = stop or asyncio.Event()
        async with asyncio.TaskGroup() as group:
            group.create_task(self._watch(stop), name="watcher-events")
            self.scan()
            group.create_task(self._settle(stop), name="watcher-settle")
            group.create_task(self._rescan(stop), name="watcher-rescan")

    async def _rescan(self, stop: asyncio.Event) -> None:
        """Scan again now and then: network shares and event overflows can miss changes."""
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(self.rescan_s):
                    await stop.wait()
            if not stop.is_set():
                self.scan()

    def scan(self) -> None:
        """Add every job-named entry of the folder to the candidates."""
        with os.scandir(self.folder) as entries:
            for entry in entries:
                self._consider(Path(entry.path))

    def _consider(self, path: Path) -> None:
        if path.parent != self.folder or not is_job_name(path.name):
            return
        if path not in self._pending:
            self._pending[path] = _Seen(None, time.monotonic())
            self._wake.set()
            if self.on_seen is not None:
                try:
                    self.on_seen(path)
                except Exception:  # work begun ahead is optional; taking the file is not
                    log.exception("work ahead on %s failed", path.name)

    async def _watch(self, stop: asyncio.Event) -> None:
        async for changes in awatch(
            self.folder, watch_filter=None, recursive=False, stop_event=stop,
            debounce=50, step=20,
        ):
            for _change, name in changes:
                self._consider(Path(name))

    async def _settle(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            self._wake.clear()
            now = time.monotonic()
            due: list[Path] = []
            wait = None
            for path, seen in list(self._pending.items()):
                signature = _signature(path)
                if signature is None and not path.is_symlink():
                    del self._pending[path]  # gone before it settled
                    self._looks.pop(path, None)
                    continue
                if signature != seen.signature:
                    since = _changed_at(signature, now, self.settle_s)
                    self._pending[path] = _Seen(signature, since)
                    remaining = self.settle_s - (now - since)
                else:
                    remaining = self.settle_s - (now - seen.since)
                if remaining <= 0:
                    due.append(path)
                    continue
                half = remaining - self.settle_s / 2
                if half <= 0:  # held still for half its settle time
                    self._look_early(path, self._pending[path].signature)
                step = remaining if half <= 0 else half  # wake at halfway, then when due
                wait = step if wait is None else min(wait, step)
            due.sort(key=lambda item: (_mtime(self._pending[item]), item.name))  # oldest first
            for path in list(due):
                if path.is_file() and await self._written(path, self._pending[path].signature):
                    # still being written, however long it has been still: wait again
                    if path not in self._held:
                        self._held.add(path)
                        log.info("%s is still open for writing; waiting for its writer",
                                 path.name)
                    # looked at again shortly: settled already, it is taken once closed
                    again = min(self.settle_s, _HELD_RECHECK_S)
                    self._pending[path] = _Seen(self._pending[path].signature,
                                                time.monotonic() - self.settle_s + again)
                    due.remove(path)
                    wait = again if wait is None else min(wait, again)
            for path in due:
                self._held.discard(path)
                self._looks.pop(path, None)
                del self._pending[path]
                try:
                    await self.on_settled(path)
                except Exception:  # one bad file must not stop the watcher
                    log.exception("taking %s failed", path.name)
            if due:
                continue
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(_poll_interval(wait)):
                    await self._wake.wait()


    def _look_early(self, path: Path, signature: tuple[int, int, int, int] | None) -> None:
        """Begin looking for writers of a file that has held still for half its settle time."""
        look = self._looks.get(path)
        if look is not None and look[0] == signature:
            return
        if look is not None and not look[1].done():
            return  # one look at a time; the signature check at the end decides
        self._looks[path] = (signature, asyncio.ensure_future(
            asyncio.to_thread(open_for_writing, path)))
        if self.on_still is not None and path.is_file():
            try:
                self.on_still(path)
            except Exception:  # work begun ahead is optional; taking the file is not
                log.exception("work ahead on %s failed", path.name)

    async def _written(self, path: Path, signature: tuple[int, int, int, int] | None) -> bool:
        """True when a process holds ``path`` open for writing.

        The answer of a look begun while the file settled is used when the file has
        not changed since; a writer that stalls keeps its descriptor open all along.
        """
        look = self._looks.pop(path, None)
        if look is not None and look[0] == signature:
            return await look[1]
        return await asyncio.to_thread(open_for_writing, path)


def _poll_interval(wait: float | None) -> float | None:
    """How long to sleep: until the next candidate may settle, re-checked at least 4x/s."""
    if wait is None:
        return None
    return max(0.001, min(wait, 0.25))


def _changed_at(signature: tuple[int, int, int, int] | None, now: float, settle_s: float) -> float:
    """When (monotonic s) a path last changed, as its status-change time says.

    The settle time then runs from the change itself rather than from the moment
    its event was delivered and looked at. A change time in the future or older
    than ``settle_s`` (a clock that differs, as on some network shares, or a file
    present before it was first seen) is not trusted: the time runs from ``now``.
    """
    if signature is None:
        return now
    # file times come from a coarse clock, up to one of its ticks behind the exact time:
    # the change is taken to be one tick after its stamp, even when that is a moment
    # from now, so that files stamped in the same tick settle together (and are taken
    # in the order of their names, not of when each was first looked at)
    age = time.time() - signature[3] / 1e9 - _STAMP_GRAIN_S
    return now - age if -_STAMP_GRAIN_S <= age <= settle_s else now


def _mtime(seen: _Seen) -> int:
    return seen.signature[1] if seen.signature is not None else 0


def _signature(path: Path) -> tuple[int, int, int, int] | None:
    """(size, mtime ns, kind, ctime ns) of a path, not following links; None when it is gone."""
    try:
        stat = path.lstat()
    except OSError:
        return None
    return (stat.st_size, stat.st_mtime_ns, stat.st_mode, stat.st_ctime_ns)
