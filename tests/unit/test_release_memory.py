"""Memory between jobs: a finished job's last thread is waited for, then released."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import threading
import weakref
from collections.abc import Iterator

from hostd.app.memory import release_again, release_once_ended


@contextlib.contextmanager
def collector_off() -> Iterator[None]:
    """The cyclic collector paused in the block: only the release's collection may free
    a cycle made there."""
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


class Measuring:
    """A stand-in for the ETA's measuring thread: a wait that returns once let go, and
    a reference cycle (a plan and its layers) that only a collection frees."""

    def __init__(self) -> None:
        self.let_go = threading.Event()
        self.plan: list[object] = [bytearray(1 << 16)]
        self.plan.append(self)  # a cycle: reference counting alone does not free it
        self.waited = False

    def wait_measured(self, timeout: float | None = None) -> bool:
        self.waited = self.let_go.wait(timeout)
        return self.waited


def test_released_once_the_thread_ended_and_nothing_of_it_is_held():
    async def scenario() -> tuple[bool, bool, weakref.ref[Measuring]]:
        with collector_off():
            thread = Measuring()
            ref = weakref.ref(thread)
            task = asyncio.create_task(release_once_ended(thread.wait_measured, lambda: True))
            await asyncio.sleep(0.05)
            pending = not task.done()  # still waiting for the thread
            thread.let_go.set()
            del thread
            return pending, await task, ref

    pending, released, ref = asyncio.run(scenario())
    assert pending
    assert released
    assert ref() is None, "the measured plan was still held when the heap was released"


def test_not_released_when_the_next_job_began():
    thread = Measuring()
    thread.let_go.set()
    assert asyncio.run(release_once_ended(thread.wait_measured, lambda: False)) is False
    assert thread.waited


class Cycle:
    """What a job's end leaves: a reference cycle only a collection frees."""

    def __init__(self) -> None:
        self.me = self


def test_released_again_after_the_job_ended_while_idle():
    async def scenario() -> tuple[bool, bool, weakref.ref[Cycle]]:
        with collector_off():
            ref = weakref.ref(Cycle())  # freed to the collector only
            task = asyncio.create_task(release_again(lambda: True, delay_s=0.05))
            await asyncio.sleep(0)
            before = ref() is not None and not task.done()  # not yet: it waits first
            return before, await task, ref

    waited, released, ref = asyncio.run(scenario())
    assert waited
    assert released
    assert ref() is None


def test_not_released_again_when_the_next_job_began():
    with collector_off():
        ref = weakref.ref(Cycle())
        assert asyncio.run(release_again(lambda: False, delay_s=0.01)) is False
        assert ref() is not None  # no collection ran
    gc.collect()
