"""Stopping asyncio tasks without losing a cancellation on Python 3.11.

Two 3.11 behaviours make a task run on after it was told to stop:

- ``task.cancel(); with suppress(CancelledError): await task`` also swallows a
  cancellation of the *caller* that arrives while it waits;
- :func:`asyncio.wait_for` (which aiomqtt uses for every acknowledgement)
  returns the result when the awaited thing completes in the same loop
  iteration as the cancellation, which is then lost.

In both cases the task's cancellation count (:meth:`asyncio.Task.cancelling`)
still went up. It is compared before and after, never read alone: a task
group on 3.11 can leave a count behind when a child fails while it exits.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import Any, TypeVar

T = TypeVar("T")


def _cancellations() -> int:
    task = asyncio.current_task()
    return task.cancelling() if task is not None else 0


def cancel_requests() -> int:
    """How many times the current task has been asked to stop (0 outside a task): read
    before a call that may swallow a cancellation, for :func:`raise_if_cancelled_since`."""
    return _cancellations()


def raise_if_cancelled_since(before: int) -> None:
    """Raise :class:`asyncio.CancelledError` when the current task was asked to stop
    since :func:`cancel_requests` gave ``before``: a cancellation that an awaited call
    (aiomqtt's connect, on 3.11) turned into its own error is not lost."""
    if _cancellations() > before:
        raise asyncio.CancelledError


async def cancel_safe(awaitable: Awaitable[T]) -> T:
    """Await ``awaitable``; raise :class:`asyncio.CancelledError` if the current task was
    asked to stop meanwhile, even when the awaitable swallowed the cancellation."""
    before = _cancellations()
    result = await awaitable
    if _cancellations() > before:
        raise asyncio.CancelledError
    return result


async def cancel_and_wait(task: asyncio.Future[Any]) -> None:
    """Cancel ``task`` and wait until it has finished; its own cancellation is not an error.

    A cancellation of the caller that arrives during the wait propagates.
    """
    before = _cancellations()
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        if _cancellations() > before:
            raise
