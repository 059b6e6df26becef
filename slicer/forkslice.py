"""Forked worker processes as an engine of the layer window: layers made in other
processes, their G-code text streamed back.

Each worker is a ``fork`` of the process that holds the plan (nothing is copied
or pickled to start it) and slices every ``workers``-th task (a task is a range
of layers, made by one call: layers made together cost less each). It sends
each layer back on a pipe as a fixed header (text length,
filament mm, time s) and the ASCII text; a thread here drains each pipe into
the layers' futures, so a worker never waits on the writer. A worker starts a
task only with a credit, and a credit is given when the
:class:`~slicer.pipeline.LayerWindow` submits the task's first layer: the
window's depth bounds what is held, so memory does not grow with the model.
Plain ``os.fork`` and pipes: the multiprocessing package (and what it imports)
is not needed.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import os
import signal
import struct
import threading
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import BinaryIO

from slicer.pipeline import Pending

LayerText = tuple[str, float, float]  # (G-code text, filament mm, time s)
# the layers lo..hi-1 of a task, made together
MakeTask = Callable[[int, int], Sequence[LayerText]]


def per_layer(layer: Callable[[int], LayerText]) -> MakeTask:
    """A task maker that makes its layers one by one with ``layer(i)``."""
    return lambda lo, hi: [layer(i) for i in range(lo, hi)]

_HEADER = struct.Struct("<qdd")  # text length (negative: a pickled error follows), mm, s


class ForkedLayers:
    """The layers of ``tasks`` (ranges ``[lo, hi)``, increasing), each task made by one
    call ``make(lo, hi)`` in one of ``workers`` forked processes (task ``k`` by worker
    ``k % workers``).

    :meth:`submit` is a :class:`~slicer.pipeline.LayerWindow` engine: layers must
    be submitted in order, and submitting a task's first layer lets its worker
    start it. An exception raised by ``make`` in a worker is raised by the
    layer's future (the same type when it can be pickled). :meth:`close` (or
    leaving the ``with`` block) ends the workers, killing them if layers are
    still unmade. Needs ``os.fork`` (POSIX).
    """

    def __init__(
        self, make: MakeTask, tasks: Sequence[tuple[int, int]], workers: int
    ) -> None:
        tasks = list(tasks)
        self._workers: list[_Worker] = []
        self._first_of: dict[int, int] = {lo: k for k, (lo, _hi) in enumerate(tasks)}
        # each future is held here until submitted and by its worker's reader until
        # made: then only by the window, until taken
        self._futures: dict[int, Pending[LayerText]] = {
            i: Pending() for lo, hi in tasks for i in range(lo, hi)
        }
        self._closed = False
        if not tasks:
            return
        workers = max(1, min(workers, len(tasks)))
        gc.freeze()  # objects made so far stay out of the workers' collections: fewer pages
        try:
            for w in range(workers):
                self._workers.append(_Worker.fork(make, tasks[w::workers], self._workers))
        finally:
            gc.unfreeze()
        for worker in self._workers:  # threads only once every fork is done
            worker.start_reading(self._futures)

    def submit(self, index: int) -> Pending[LayerText]:
        """Layer ``index``'s future; the first layer of a task starts its worker on it."""
        task = self._first_of.get(index)
        if task is not None:
            self._workers[task % len(self._workers)].credit()
        return self._futures.pop(index)

    def close(self) -> None:
        """Let the workers go (killed when they still owe layers) and reap them."""
        if self._closed:
            return
        self._closed = True
        for worker in self._workers:
            worker.stop(kill=not worker.finished)

    def __enter__(self) -> ForkedLayers:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()


class _Worker:
    """One forked worker seen from the parent: its pid, credit pipe and result pipe."""

    def __init__(self, pid: int, credits: int, stream: BinaryIO,
                 tasks: Sequence[tuple[int, int]]) -> None:
        self.pid = pid
        self._credits = credits
        self._stream = stream
        self._tasks = tasks
        self._reader: threading.Thread | None = None
        self.finished = False  # every layer of its tasks read back

    def start_reading(self, futures: dict[int, Pending[LayerText]]) -> None:
        """Drain the worker's pipe into its layers' ``futures`` on a thread."""
        mine = collections.deque(
            [futures[i] for i in range(lo, hi)] for lo, hi in self._tasks
        )
        self._reader = threading.Thread(
            target=self._drain, args=(mine,), name=f"layers-{self.pid}", daemon=True
        )
        self._reader.start()

    def _drain(self, mine: collections.deque[list[Pending[LayerText]]]) -> None:
        """On a thread of the parent: read each of the worker's tasks from its pipe and
        give its layers to the next futures of ``mine`` (a task's all at once: the
        writer wakes once a task, not once a layer); on an error, fail the layers not
        made and every later one (no taker is left waiting)."""
        try:
            with self._stream as stream:
                while mine:
                    made = []
                    for _future in mine[0]:
                        length, filament, seconds = _HEADER.unpack(
                            _read_exact(stream, _HEADER.size))
                        if length < 0:
                            import pickle

                            raise pickle.loads(_read_exact(stream, -length))
                        made.append((_read_exact(stream, length).decode("ascii"), filament,
                                     seconds))
                    # the last first: the writer, waiting for the first, then finds
                    # the rest made
                    for future, layer in reversed(list(zip(mine.popleft(), made,
                                                           strict=True))):
                        future.set_result(layer)
            self.finished = True
        except BaseException as exc:
            while mine:
                for future in mine.popleft():
                    future.set_exception(exc)

    @classmethod
    def fork(
        cls,
        make: MakeTask,
        tasks: Sequence[tuple[int, int]],
        siblings: Sequence[_Worker],
    ) -> _Worker:
        """Start a worker slicing ``tasks``; ``siblings`` are the workers started before
        (the new process closes its copies of their pipes)."""
        result_r, result_w = os.pipe()
        credit_r, credit_w = os.pipe()
        pid = os.fork()
        if pid == 0:  # the worker: never returns
            os.close(result_r)
            os.close(credit_w)
            for sibling in siblings:
                sibling._close_in_child()
            _work(make, tasks, credit_r, result_w)
        os.close(result_w)
        os.close(credit_r)
        return cls(pid, credit_w, os.fdopen(result_r, "rb"), tasks)

    def credit(self) -> None:
        """Let the worker start one more task."""
        with contextlib.suppress(BrokenPipeError):  # it has finished its tasks and exited
            os.write(self._credits, b"\x01")

    def stop(self, kill: bool) -> None:
        """Close the credit pipe (a waiting worker exits), kill the worker if asked, reap it."""
        os.close(self._credits)
        if kill:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
        os.waitpid(self.pid, 0)
        if self._reader is not None:
            self._reader.join()
        else:
            self._stream.close()

    def _close_in_child(self) -> None:
        os.close(self._credits)
        os.close(self._stream.fileno())


def _work(
    make: MakeTask, tasks: Sequence[tuple[int, int]], credit_r: int, result_w: int,
) -> None:
    """In the worker: slice each task after taking a credit, send it, exit (no cleanup
    handlers of the parent's run here)."""
    code = 0
    try:
        for lo, hi in tasks:
            if os.read(credit_r, 1) == b"":  # the parent closed: nothing more is wanted
                break
            out = bytearray()
            made = make(lo, hi)
            if len(made) != hi - lo:
                raise RuntimeError(f"layers {lo}-{hi - 1}: {len(made)} made")
            for text, filament, seconds in made:
                data = text.encode("ascii")
                out += _HEADER.pack(len(data), filament, seconds)
                out += data
            _write_all(result_w, out)
    except BaseException as exc:  # sent to the parent, which raises it
        code = 1
        with contextlib.suppress(BaseException):
            _write_all(result_w, _error_record(exc))
    finally:
        os._exit(code)


def _error_record(exc: BaseException) -> bytes:
    """A header with a negative length and the pickled exception (or a RuntimeError
    naming it when it cannot be pickled)."""
    import pickle

    try:
        blob = pickle.dumps(exc)
        pickle.loads(blob)
    except Exception:
        blob = pickle.dumps(RuntimeError(f"slicing a layer failed in a worker: {exc!r}"))
    return _HEADER.pack(-len(blob), 0.0, 0.0) + blob


def _write_all(fd: int, data: bytes | bytearray) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _read_exact(stream: BinaryIO, n: int) -> bytes:
    data = stream.read(n)
    if len(data) != n:
        raise RuntimeError("a slicing worker ended before sending its layers")
    return data
