"""The whole-model pass begun while a dropped model settles, taken by its job if nothing changed.

A dropped file is taken once it has held still for ``jobs.settle_s``; the
printer then waits for the whole-model pass and the first layer. When the
printer is idle and nothing else waits, that pass and layer 0's G-code can
begin halfway through the settle time instead, from the file as it is then.
The job takes the result only
if the file is the very one that was read (same device, inode, size and
modification time: moving it into the job's folder keeps all four) and the
settings are the same; otherwise the pass is made again, as without this. The
model's hash is still checked before slicing, so a plan never outlives its bytes.
"""

from __future__ import annotations

import asyncio
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from slicer.output.gcode import LayerCode
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

log = logging.getLogger("hostd.jobs.speculate")

Identity = tuple[int, int, int, int]  # st_dev, st_ino, st_size, st_mtime_ns


def identity(path: Path | int) -> Identity | None:
    """What tells this file's bytes apart without reading them (``path`` or an open
    descriptor); None when unreadable."""
    try:
        info = os.stat(path)
    except OSError:
        return None
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)


def is_plain(settings: SliceSettings) -> bool:
    """Whether a job's plan is the file's plan alone: no analysis, no mass to match."""
    return (settings.infill_field != "stress" and not settings.infill_load
            and not settings.infill_match_mass_of and settings.infill_target_mass_g <= 0)


class MadeAhead(NamedTuple):
    """What was made while the file settled: the plan, the seconds its whole-model pass
    took, and layer 0's G-code (no body left out; None if slicing it failed)."""

    plan: SlicePlan
    seconds: float
    first_layer: LayerCode | None


@dataclass
class _Pass:
    key: Identity
    settings: SliceSettings
    bed: tuple[float, float, float]
    future: asyncio.Future[MadeAhead | None]


class Speculation:
    """At most one whole-model pass made ahead of its job (the latest begun)."""

    def __init__(self) -> None:
        self._pass: _Pass | None = None

    def begin(self, path: Path, settings: SliceSettings, bed: tuple[float, float, float]) -> bool:
        """Start the pass of ``path`` in a worker thread (once per file version); True if
        begun now. Plans with an analysis or a mass to match are not made ahead."""
        key = identity(path)
        if key is None or not is_plain(settings):
            return False
        held = self._pass
        if held is not None and (held.key, held.settings, held.bed) == (key, settings, bed):
            return False
        try:  # opened now: the intake may move the file before the thread reads it
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            return False
        future = asyncio.ensure_future(asyncio.to_thread(_whole_model_pass, fd, path.name,
                                                         key, settings, bed))
        future.add_done_callback(_quiet)
        self._pass = _Pass(key, settings, bed, future)
        return True

    def forget(self) -> None:
        """Drop the pass held (its thread finishes, its plan is freed)."""
        self._pass = None

    async def take(
        self, path: Path, settings: SliceSettings, bed: tuple[float, float, float]
    ) -> MadeAhead | None:
        """The plan (and layer 0) made ahead for exactly this file and these settings;
        None when there is none (the caller makes the pass itself)."""
        held, self._pass = self._pass, None
        if held is None or (held.settings, held.bed) != (settings, bed):
            return None
        if identity(path) != held.key:
            return None
        return await held.future


def _whole_model_pass(
    fd: int, name: str, key: Identity, settings: SliceSettings,
    bed: tuple[float, float, float],
) -> MadeAhead | None:
    """The plan of the file open as ``fd`` (closed here) if it still is ``key`` after it
    was read, else None; with it layer 0's G-code, the first thing the printer waits
    for. Read through the descriptor, the file may be moved meanwhile (a rename keeps
    its bytes and its identity)."""
    started = time.monotonic()
    try:
        if identity(fd) != key:
            return None
        plan = SlicePlan.from_file(f"/proc/self/fd/{fd}", settings, bed)
        if identity(fd) != key:
            return None
    except Exception:  # a file still being written: the job's own pass reports it
        log.debug("whole-model pass of %s ahead of its job failed", name, exc_info=True)
        return None
    finally:
        os.close(fd)
    seconds = time.monotonic() - started
    try:  # the same call the job's schedule makes for layer 0: the same bytes
        first: LayerCode | None = plan.layer_code(0) if plan.layer_count else None
    except Exception:  # the job slices it again and reports what is wrong
        log.debug("layer 0 of %s ahead of its job failed", name, exc_info=True)
        first = None
    return MadeAhead(plan, seconds, first)


def _quiet(future: asyncio.Future[MadeAhead | None]) -> None:
    """Retrieve an abandoned pass's outcome so that nothing is logged for it."""
    if not future.cancelled():
        future.exception()
