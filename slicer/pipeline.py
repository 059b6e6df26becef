"""The layer pipeline: layers made a bounded window ahead of the one consumed, in order."""

from __future__ import annotations

import collections
import concurrent.futures
import threading
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")


class LayerWindow(Generic[T]):
    """Layers ``first..count-1`` made by ``submit(index)``, at most ``depth`` ahead.

    ``submit`` starts making one layer and returns its future (a thread pool's,
    or any object with ``done()``, ``result()``, ``cancel()`` and
    ``add_done_callback()``). A layer is submitted only when one is taken, so
    memory holds at most ``depth`` layers however many there are
    (backpressure). With ``alone`` set, layers are made one at a time until one
    is "worth" something (``worth(result)`` true): the first layers a printer
    waits for do not compete with the ones after them.

    Take layers in order with :meth:`take` (blocking), ``await``
    :meth:`take_async`, or by iterating; :meth:`close` drops pending work.
    """

    def __init__(
        self,
        submit: Callable[[int], concurrent.futures.Future[T]],
        count: int,
        depth: int,
        first: int = 0,
        alone: bool = False,
        worth: Callable[[T], bool] | None = None,
    ) -> None:
        if depth < 1:
            raise ValueError(f"depth must be at least 1, got {depth}")
        self.submit = submit
        self.count = count
        self.depth = depth
        self._futures: collections.deque[tuple[int, concurrent.futures.Future[T]]] = (
            collections.deque()
        )
        self._next = first
        self._closed = False
        self._alone = alone
        self._worth = worth or (lambda _result: True)
        self._lock = threading.RLock()  # a layer made alone refills from its worker thread
        self._fill()

    def _fill(self) -> None:
        with self._lock:
            while not self._closed and len(self._futures) < self.depth and (
                self._next < self.count
            ):
                if self._alone and any(not f.done() for _index, f in self._futures):
                    return
                index = self._next
                future = self.submit(index)
                self._futures.append((index, future))
                self._next += 1
                if self._alone:
                    future.add_done_callback(self._made_alone)

    def _made_alone(self, future: concurrent.futures.Future[T]) -> None:
        if future.cancelled() or future.exception() is not None or self._worth(future.result()):
            self._alone = False  # from now on, the full window
        self._fill()

    def _head(self, index: int | None) -> concurrent.futures.Future[T]:
        with self._lock:
            if not self._futures:
                self._fill()
            if not self._futures:
                raise IndexError("no layer left")
            queued, future = self._futures[0]
            if index is not None and queued != index:
                raise RuntimeError(f"layer {index} asked for, layer {queued} is next")
            return future

    def _pop(self) -> None:
        with self._lock:
            self._futures.popleft()
        self._fill()

    def take(self, index: int | None = None) -> T:
        """The next layer (``index``, when given, must be it); waits until it is made."""
        result = self._head(index).result()
        self._pop()
        return result

    async def take_async(self, index: int | None = None) -> T:
        """:meth:`take` for a coroutine: the event loop runs on while the layer is made."""
        import asyncio  # only the daemon awaits layers: `hostd slice` never loads asyncio

        future = self._head(index)
        result = await asyncio.wrap_future(future)
        self._pop()
        return result

    def __iter__(self) -> Iterator[T]:
        while self.next_unsliced < self.count or self._futures:
            yield self.take()

    def made(self, index: int) -> T | None:
        """Layer ``index`` if it is made and not taken yet, else None; never waits, and the
        layer stays in the window for :meth:`take`."""
        with self._lock:
            for queued, future in self._futures:
                if queued == index:
                    if future.done() and not future.cancelled() and future.exception() is None:
                        return future.result()
                    return None
        return None

    @property
    def ready_ahead(self) -> int:
        """Layers already made and not yet taken."""
        with self._lock:
            return sum(1 for _index, future in self._futures if future.done())

    @property
    def next_unsliced(self) -> int:
        """The first layer not yet submitted."""
        return self._next

    def close(self) -> None:
        """Submit nothing more and cancel what has not started."""
        with self._lock:
            self._closed = True
            for _index, future in self._futures:
                future.cancel()
            self._futures.clear()
