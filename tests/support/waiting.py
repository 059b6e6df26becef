"""Waiting for a condition with a deadline: the one polling helper the tests share.

A test waits for what it needs to have happened, never for a fixed time: the
condition is polled every ``interval`` seconds and the wait fails (an
AssertionError naming what was awaited) once ``timeout`` seconds pass.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

Described = str | Callable[[], object]  # what is awaited, or a function showing what was seen


async def until(check: Callable[[], T], timeout: float = 30.0, what: Described = "the condition",
                interval: float = 0.02) -> T:
    """Wait in the event loop until ``check()`` is true; return its value.

    Fails after ``timeout`` s, naming ``what`` (a text, or a function whose result,
    what was seen instead, is shown).
    """
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        result = check()
        if result:
            return result
        if loop.time() > deadline:
            raise AssertionError(_timed_out(what, timeout))
        await asyncio.sleep(interval)


def wait_until(check: Callable[[], T], timeout: float = 30.0, what: Described = "the condition",
               interval: float = 0.02) -> T:
    """:func:`until` for a thread that is not an event loop's (it blocks)."""
    deadline = time.monotonic() + timeout
    while True:
        result = check()
        if result:
            return result
        if time.monotonic() > deadline:
            raise AssertionError(_timed_out(what, timeout))
        time.sleep(interval)


def _timed_out(what: Described, timeout: float) -> str:
    if callable(what):
        return f"condition not met within {timeout} s: {what()!r}"
    return f"timed out after {timeout} s waiting for {what}"
