"""Forked worker processes as an engine of the layer window: layers made in other
processes, their G-code text streamed back.

Each worker is a ``fork`` of the process that holds the plan (nothing is copied
or pickled to start it) and slices tasks (a task is a range of layers, made by
one call: layers made together cost less each), whichever task is next when it
is free: tasks differ in cost (a plate's bottom skins, a sphere's middle), and
handed out in turn one worker had finished its share while the other still
worked on its own. A task is handed out when the
:class:`~slicer.pipeline.LayerWindow` submits its first layer, on one pipe all
workers read (one 4-byte record a task, which one reader takes whole): the
window's depth bounds what is held, so memory does not grow with the model.
A worker sends each task back on its own pipe: the task's number as soon as it
takes it, then each layer as a fixed header (text length, filament mm, time s)
and the ASCII text; a thread here drains each pipe into the layers' futures, so
a worker never waits on the writer. Plain ``os.fork`` and pipes: the
multiprocessing package (and what it imports) is not needed.
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import struct
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, InvalidStateError
from types import TracebackType
from typing import BinaryIO

LayerText = tuple[str, float, float]  # (G-code text, filament mm, time s)
# the layers lo..hi-1 of a task, made together
MakeTask = Callable[[int, int], Sequence[LayerText]]


def per_layer(layer: Callable[[int], LayerText]) -> MakeTask:
    """A task maker that makes its layers one by one with ``layer(i)``."""
    return lambda lo, hi: [layer(i) for i in range(lo, hi)]

_HEADER = struct.Struct("<qdd")  # text length (negative: a pickled error follows), mm, s
_TASK = struct.Struct("<i")  # a task's number: handed to the workers, and sent back first


class ForkedLayers:
    """The layers of ``tasks`` (ranges ``[lo, hi)``, increasing), each task made by one
    call ``make(lo, hi)`` in one of ``workers`` forked processes, the first of them
    free when the task is handed out.

    :meth:`submit` is a :class:`~slicer.pipeline.LayerWindow` engine: layers must
    be submitted in order, and submitting a task's first layer hands the task
    out. An exception raised by ``make`` in a worker is raised by the layers'
    futures of its task (the same type when it can be pickled); a worker that
    ends without sending a task it took fails that task, and once no worker is
    left every layer not made fails. :meth:`close` (or leaving the ``with``
    block) ends the workers, killing them if layers are still unmade. Needs
    ``os.fork`` (POSIX).
    """

    def __init__(
        self, make: MakeTask, tasks: Sequence[tuple[int, int]], workers: int
    ) -> None:
        tasks = list(tasks)
        self._workers: list[_Worker] = []
        self._first_of: dict[int, int] = {lo: k for k, (lo, _hi) in enumerate(tasks)}
        # each future is held here until submitted and by the task's list until made:
        # then only by the window, until taken
        self._futures: dict[int, Future[LayerText]] = {
            i: Future() for lo, hi in tasks for i in range(lo, hi)
        }
        self._task_futures = [[self._futures[i] for i in range(lo, hi)] for lo, hi in tasks]
        self._lock = threading.Lock()
        self._made = 0  # tasks read back whole
        self._reading = 0  # workers whose pipe is still read
        self._closed = False
        self._hand_out = -1
        if not tasks:
            return
        workers = max(1, min(workers, len(tasks)))
        hand_r, self._hand_out = os.pipe()
        gc.freeze()  # objects made so far stay out of the workers' collections: fewer pages
        try:
            for _ in range(workers):
                self._workers.append(_Worker.fork(make, tasks, hand_r, self._hand_out,
                                                  self._workers))
        finally:
            gc.unfreeze()
            os.close(hand_r)
        self._reading = len(self._workers)
        for worker in self._workers:  # threads only once every fork is done
            worker.start_reading(self._task_futures, self._ended)

    @property
    def finished(self) -> bool:
        """Every task's layers read back."""
        with self._lock:
            return self._made == len(self._task_futures)

    def submit(self, index: int) -> Future[LayerText]:
        """Layer ``index``'s future; the first layer of a task hands the task out."""
        task = self._first_of.get(index)
        if task is not None:
            with contextlib.suppress(BrokenPipeError):  # no worker left: its futures fail
                os.write(self._hand_out, _TASK.pack(task))
        return self._futures.pop(index)

    def close(self) -> None:
        """Let the workers go (killed when layers are still unmade) and reap them."""
        if self._closed:
            return
        self._closed = True
        kill = not self.finished
        if self._hand_out >= 0:
            os.close(self._hand_out)  # a worker waiting for a task exits
        for worker in self._workers:
            worker.stop(kill=kill)

    def __enter__(self) -> ForkedLayers:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _ended(self, made: int, error: BaseException | None) -> None:
        """A worker's pipe is read to its end, after ``made`` tasks: once none is left,
        every layer not made fails (no worker will make it)."""
        with self._lock:
            self._made += made
            self._reading -= 1
            last = self._reading == 0
        if last:
            gone = error or RuntimeError("the slicing workers ended before sending their layers")
            for futures in self._task_futures:
                for future in futures:
                    _fail(future, gone)  # not the futures already made or cancelled


class _Worker:
    """One forked worker seen from the parent: its pid and result pipe."""

    def __init__(self, pid: int, stream: BinaryIO) -> None:
        self.pid = pid
        self._stream = stream
        self._reader: threading.Thread | None = None

    def start_reading(
        self, task_futures: list[list[Future[LayerText]]],
        ended: Callable[[int, BaseException | None], None],
    ) -> None:
        """Drain the worker's pipe into its tasks' futures on a thread; ``ended(tasks
        made, error or None)`` is called when the pipe ends."""
        self._reader = threading.Thread(
            target=self._drain, args=(task_futures, ended), name=f"layers-{self.pid}",
            daemon=True,
        )
        self._reader.start()

    def _drain(
        self, task_futures: list[list[Future[LayerText]]],
        ended: Callable[[int, BaseException | None], None],
    ) -> None:
        """On a thread of the parent: read each task the worker sends (its number, then
        its layers) and give its layers to the task's futures (all at once: the writer
        wakes once a task, not once a layer); on an error, or an end in the middle of
        a task, fail the layers of that task."""
        made = 0
        error: BaseException | None = None
        futures: list[Future[LayerText]] = []
        try:
            with self._stream as stream:
                while True:
                    head = stream.read(_TASK.size)
                    if not head:  # between tasks: no more to hand out, or killed
                        break
                    if len(head) != _TASK.size:
                        raise RuntimeError("a slicing worker ended before sending its layers")
                    task = _TASK.unpack(head)[0]
                    if task < 0:  # the worker failed before taking a task: its error
                        _raise_error(stream)
                    futures = task_futures[task]
                    layers = []
                    for _future in futures:
                        length, filament, seconds = _HEADER.unpack(
                            _read_exact(stream, _HEADER.size))
                        if length < 0:
                            _raise_error(stream, -length)
                        layers.append((_read_exact(stream, length).decode("ascii"), filament,
                                       seconds))
                    # the last first: the writer, waiting for the first, then finds
                    # the rest made
                    for future, layer in reversed(list(zip(futures, layers, strict=True))):
                        with contextlib.suppress(InvalidStateError):  # cancelled: dropped
                            future.set_result(layer)
                    futures = []
                    made += 1
        except BaseException as exc:
            error = exc
            for future in futures:
                _fail(future, exc)
        ended(made, error)

    @classmethod
    def fork(
        cls,
        make: MakeTask,
        tasks: Sequence[tuple[int, int]],
        hand_r: int,
        hand_w: int,
        siblings: Sequence[_Worker],
    ) -> _Worker:
        """Start a worker slicing the ``tasks`` handed out on pipe ``hand_r`` (``hand_w``
        its other end, the parent's); ``siblings`` are the workers started before (the
        new process closes its copies of their pipes)."""
        result_r, result_w = os.pipe()
        pid = os.fork()
        if pid == 0:  # the worker: never returns
            os.close(result_r)
            os.close(hand_w)
            for sibling in siblings:
                sibling._close_in_child()
            _work(make, tasks, hand_r, result_w)
        os.close(result_w)
        return cls(pid, os.fdopen(result_r, "rb"))

    def stop(self, kill: bool) -> None:
        """Kill the worker if asked, reap it, and wait for its pipe to be read."""
        if kill:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)
        os.waitpid(self.pid, 0)
        if self._reader is not None:
            self._reader.join()
        else:
            self._stream.close()

    def _close_in_child(self) -> None:
        os.close(self._stream.fileno())


def _work(
    make: MakeTask, tasks: Sequence[tuple[int, int]], hand_r: int, result_w: int,
) -> None:
    """In the worker: take the next task handed out, send its number, slice it, send
    it; exit when no more are handed out (no cleanup handlers of the parent's run
    here)."""
    code = 0
    taken = False  # a task's number sent, its layers not yet
    try:
        while True:
            record = os.read(hand_r, _TASK.size)
            if not record:  # the parent closed: nothing more is wanted
                break
            if len(record) != _TASK.size:
                raise RuntimeError("a task number came cut in two")
            task = _TASK.unpack(record)[0]
            write_all(result_w, record)
            taken = True
            lo, hi = tasks[task]
            made = make(lo, hi)
            if len(made) != hi - lo:
                raise RuntimeError(f"layers {lo}-{hi - 1}: {len(made)} made")
            out = bytearray()
            for text, filament, seconds in made:
                data = text.encode("ascii")
                out += _HEADER.pack(len(data), filament, seconds)
                out += data
            write_all(result_w, out)
            taken = False
    except BaseException as exc:  # sent to the parent, which raises it
        code = 1
        with contextlib.suppress(BaseException):
            write_all(result_w, (b"" if taken else _TASK.pack(-1)) + _error_record(exc))
    finally:
        os._exit(code)


def _fail(future: Future[LayerText], error: BaseException) -> None:
    """Fail ``future`` with ``error`` unless it is made or cancelled already."""
    with contextlib.suppress(InvalidStateError):
        future.set_exception(error)


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


def _raise_error(stream: BinaryIO, length: int | None = None) -> None:
    """Raise the error a worker sent (its pickled exception, ``length`` bytes; when
    None, read from the header first)."""
    import pickle

    if length is None:
        length = -_HEADER.unpack(_read_exact(stream, _HEADER.size))[0]
        if length <= 0:
            raise RuntimeError("a slicing worker sent no task and no error")
    raise pickle.loads(_read_exact(stream, length))


def write_all(fd: int, data: bytes | bytearray) -> None:
    """Write all of ``data`` to the file descriptor ``fd`` (a pipe takes it in parts)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _read_exact(stream: BinaryIO, n: int) -> bytes:
    data = stream.read(n)
    if len(data) != n:
        raise RuntimeError("a slicing worker ended before sending its layers")
    return data
