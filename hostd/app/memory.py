"""Memory between jobs: what a finished job left in the process goes back to the system.

A host runs for months: each job's slicing allocates and frees tens of MB
(outlines, skins, walls, G-code text) across several threads. Once the job has
ended, :func:`release_after_job` drops the walls the slicing threads kept for the
job's islands, collects the reference cycles the job left, and asks the C
allocator to hand its free pages back (glibc ``malloc_trim``): freed memory
otherwise stayed in the process's heaps, and its RSS grew to the largest job's
working set and, with fragmentation, beyond.
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import functools
import gc
import logging
import time
from collections.abc import Callable

from slicer.paths.islands import forget_everywhere

log = logging.getLogger("hostd.app.memory")


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None where the C library has none."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        trim: Callable[[int], int] = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):  # not glibc (musl, macOS)
        return None
    return trim


def give_back() -> bool:
    """Hand the C heap's free pages back to the system; False where that is not known."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True


def _wait_from(box: list[Callable[[float | None], bool]], wait_s: float) -> None:
    """Run the one wait in ``box``, taking it out first so nothing keeps it after."""
    wait = box.pop()
    try:
        wait(wait_s)
    finally:
        del wait


def release_after_job() -> float:
    """Everything a finished job left behind in the process, released; returns the
    seconds it took (some ms: called between jobs, never while one prints)."""
    started = time.perf_counter()
    forget_everywhere()
    gc.collect()
    give_back()
    seconds = time.perf_counter() - started
    log.debug("memory of the job released in %.3f s", seconds)
    return seconds


RELEASE_AGAIN_S = 0.5  # after a job ended: its end is told meanwhile (see release_again)


async def release_again(idle: Callable[[], bool], delay_s: float = RELEASE_AGAIN_S) -> bool:
    """Release again ``delay_s`` after a job ended, if the daemon is still ``idle()``;
    True if it released. The job's end is told after the first release (its status,
    events, history and notifications), and what that work allocates and frees stayed
    in the C heap: about 2.7 MB after a mid-size job (featuretype_mm, rocker_arm), which
    a trim a second later gave back."""
    await asyncio.sleep(delay_s)
    if not idle():
        return False
    release_after_job()
    return True


async def release_once_ended(
    wait: Callable[[float | None], bool], idle: Callable[[], bool], wait_s: float = 300.0
) -> bool:
    """Release again once a finished job's last thread ended: ``wait(wait_s)`` blocks
    until it has (the ETA's measuring of the whole model goes on after a job cancelled
    early, and what it allocates is freed after :func:`release_after_job` ran). Only
    if the daemon is still ``idle()`` then; True if it released."""
    # The executor's work item outlives the call by a moment (the result wakes this
    # coroutine before the worker thread drops the item), so it must not hold the
    # bound ``wait`` (and through it the measured plan): it gets an emptied box.
    box = [wait]
    del wait
    await asyncio.to_thread(_wait_from, box, wait_s)
    if not idle():
        return False
    release_after_job()
    return True
