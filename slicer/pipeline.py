"""The layer pipeline: layers made a bounded window ahead of the one consumed, in order.

:class:`LayerWindow` is the one bounded-lookahead layer iterator; what makes the
layers is its engine, a ``submit(index)`` returning a future: :func:`in_thread`
(made by the thread that takes them), a thread pool (the daemon and
``hostd print FILE.stl``) or forked worker processes
(:class:`slicer.forkslice.ForkedLayers`, ``hostd slice``).
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from typing import Generic, TypeVar

T = TypeVar("T")


class Deferred(Future[T]):
    """A ``concurrent.futures.Future`` made by the first thread that asks for its
    :meth:`result` or :meth:`exception` (the in-thread engines): until then it is
    pending and can be cancelled; once begun it runs to its end. Layers of other
    engines are made by whoever holds their futures (a thread pool, forked workers)."""

    def __init__(self, make: Callable[[], T]) -> None:
        super().__init__()
        self._make: Callable[[], T] | None = make
        self._once = threading.Lock()

    def _run_here(self) -> None:
        with self._once:
            make, self._make = self._make, None
        if make is None or not self.set_running_or_notify_cancel():
            return  # begun by another thread, or cancelled
        try:
            value = make()
        except BaseException as exc:  # raised again by result(), as a pool's future does
            self.set_exception(exc)
        else:
            self.set_result(value)

    def result(self, timeout: float | None = None) -> T:
        """The layer, made here first if nobody began it; raises what making it raised
        (``concurrent.futures.CancelledError`` when it was cancelled)."""
        self._run_here()
        return super().result(timeout)

    def exception(self, timeout: float | None = None) -> BaseException | None:
        """What making it raised (made here first if nobody began it), or None."""
        self._run_here()
        return super().exception(timeout)


def in_thread(make: Callable[[int], T]) -> Callable[[int], Future[T]]:
    """The in-thread engine: layer ``i`` is ``make(i)``, made when it is taken, by the
    thread taking it (nothing runs beside the consumer)."""
    return lambda index: Deferred(lambda: make(index))


def in_blocks(
    make: Callable[[int, int], Sequence[T]], tasks: Sequence[tuple[int, int]]
) -> Callable[[int], Future[T]]:
    """The in-thread engine by blocks: taking a layer of task ``[lo, hi)`` (``tasks``
    cover the layers, in order) makes the whole task at once, ``make(lo, hi)``, by the
    thread taking it; the task's other layers wait made until they are taken. A layer
    in no task is made alone (``make(i, i + 1)``)."""
    task_of = {i: (lo, hi) for lo, hi in tasks for i in range(lo, hi)}
    made: dict[int, T] = {}

    def submit(index: int) -> Future[T]:
        def layer() -> T:
            if index not in made:
                lo, hi = task_of.get(index, (index, index + 1))
                made.update(zip(range(lo, hi), make(lo, hi), strict=True))
            return made.pop(index)

        return Deferred(layer)

    return submit


class LayerWindow(Generic[T]):
    """Layers ``first..count-1`` made by ``submit(index)``, at most ``depth`` ahead.

    ``submit`` is the engine: it starts making one layer and returns its
    ``concurrent.futures.Future`` (:func:`in_thread`'s :class:`Deferred`, a thread
    pool's, or forked workers'). A layer is submitted only when one is taken, so memory holds at
    most ``depth`` layers however many there are (backpressure). With ``alone``
    set, layers are made one at a time until one is "worth" something
    (``worth(result)`` true): the first layers a printer waits for do not compete
    with the ones after them.

    Take layers in order with :meth:`take` (blocking), ``await``
    :meth:`take_async`, or by iterating; :meth:`close` drops pending work.
    """

    def __init__(
        self,
        submit: Callable[[int], Future[T]],
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
        self._futures: collections.deque[tuple[int, Future[T]]] = collections.deque()
        self._next = first
        self._taken = 0
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

    def _made_alone(self, future: Future[T]) -> None:
        if future.cancelled() or future.exception() is not None or self._worth(future.result()):
            self._alone = False  # from now on, the full window
        self._fill()

    def _head(self, index: int | None) -> Future[T]:
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
            self._taken += 1
        self._fill()

    def take(self, index: int | None = None) -> T:
        """The next layer (``index``, when given, must be it); waits until it is made."""
        result = self._head(index).result()
        self._pop()
        return result

    async def take_async(self, index: int | None = None) -> T:
        """:meth:`take` for a coroutine: the event loop runs on while the layer is made
        (the engine's futures must be ``concurrent.futures.Future``: a thread pool's)."""
        import asyncio  # only the daemon awaits layers: `hostd slice` never loads asyncio

        future = self._head(index)
        if isinstance(future, Deferred):
            raise TypeError("take_async needs an engine whose layers are made elsewhere "
                            "(a thread pool or forked workers), not in the taking thread")
        result: T = await asyncio.wrap_future(future)
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

    @property
    def taken(self) -> int:
        """Layers taken so far."""
        return self._taken

    def close(self) -> None:
        """Submit nothing more and cancel what has not started."""
        with self._lock:
            self._closed = True
            for _index, future in self._futures:
                future.cancel()
            self._futures.clear()
