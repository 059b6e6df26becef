"""Layers sliced in forked worker processes, their G-code text streamed back in order.

Each worker is a ``fork`` of the process that holds the plan (nothing is copied
or pickled to start it) and slices every ``workers``-th task (a task is a range
of layers). It sends each layer back on a pipe as a fixed header (text length,
filament mm, time s) and the ASCII text; a thread here drains each pipe so a
worker never waits on the writer. A worker starts a task only with a credit,
and a credit is given back when the task's layers are taken: at most ``ahead``
tasks a worker are held, so memory does not grow with the model. Plain
``os.fork`` and pipes: the multiprocessing package (and what it imports) is
not needed.
"""

from __future__ import annotations

import contextlib
import gc
import os
import queue
import signal
import struct
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import BinaryIO

LayerText = tuple[str, float, float]  # (G-code text, filament mm, time s)

_HEADER = struct.Struct("<qdd")  # text length (negative: a pickled error follows), mm, s


def forked_layers(
    layer: Callable[[int], LayerText],
    tasks: Sequence[tuple[int, int]],
    workers: int,
    ahead: int = 2,
) -> Iterator[LayerText]:
    """``layer(i)`` for every layer of ``tasks`` (ranges ``[lo, hi)``), in task order,
    computed by ``workers`` forked processes (task ``k`` by worker ``k % workers``).

    An exception raised by ``layer`` in a worker is raised here (the same type when
    it can be pickled). Closing the iterator early stops the workers. Needs
    ``os.fork`` (POSIX).
    """
    if not tasks:
        return
    workers = max(1, min(workers, len(tasks)))
    started: list[_Worker] = []
    gc.freeze()  # objects made so far stay out of the workers' collections: fewer pages copied
    try:
        for w in range(workers):
            started.append(_Worker.fork(layer, tasks[w::workers], started, ahead))
    finally:
        gc.unfreeze()
    for worker in started:  # threads only once every fork is done
        worker.start_reading()
    finished = False
    try:
        for k in range(len(tasks)):
            worker = started[k % workers]
            kind, value = worker.results.get()
            if kind == "error":
                assert isinstance(value, BaseException)
                raise value
            assert isinstance(value, list)
            yield from value
            worker.credit()
        finished = True
    finally:
        for worker in started:
            worker.stop(kill=not finished)


class _Worker:
    """One forked worker seen from the parent: its pid, credit pipe and result queue."""

    def __init__(
        self, pid: int, credits: int, stream: BinaryIO, tasks: Sequence[tuple[int, int]]
    ) -> None:
        self.pid = pid
        self._credits = credits
        self._stream = stream
        self.results: queue.Queue[tuple[str, object]] = queue.Queue()
        self._reader = threading.Thread(
            target=_drain, args=(stream, tasks, self.results), name=f"layers-{pid}", daemon=True
        )

    def start_reading(self) -> None:
        """Drain the worker's pipe into :attr:`results` on a thread."""
        self._reader.start()

    @classmethod
    def fork(
        cls,
        layer: Callable[[int], LayerText],
        tasks: Sequence[tuple[int, int]],
        siblings: Sequence[_Worker],
        ahead: int,
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
            _work(layer, tasks, credit_r, result_w)
        os.close(result_w)
        os.close(credit_r)
        worker = cls(pid, credit_w, os.fdopen(result_r, "rb"), tasks)
        os.write(credit_w, b"\x01" * ahead)
        return worker

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
        if self._reader.is_alive() or self._reader.ident is not None:
            self._reader.join()
        else:
            self._stream.close()

    def _close_in_child(self) -> None:
        os.close(self._credits)
        os.close(self._stream.fileno())


def _work(
    layer: Callable[[int], LayerText], tasks: Sequence[tuple[int, int]], credit_r: int,
    result_w: int,
) -> None:
    """In the worker: slice each task after taking a credit, send it, exit (no cleanup
    handlers of the parent's run here)."""
    code = 0
    try:
        for lo, hi in tasks:
            if os.read(credit_r, 1) == b"":  # the parent closed: nothing more is wanted
                break
            out = bytearray()
            for i in range(lo, hi):
                text, filament, seconds = layer(i)
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


def _drain(
    stream: BinaryIO, tasks: Sequence[tuple[int, int]], results: queue.Queue[tuple[str, object]]
) -> None:
    """In a thread of the parent: read every task's layers from a worker's pipe into
    ``results`` as ("ok", [LayerText, ...]), or one ("error", exception) and stop."""
    try:
        with stream:
            for lo, hi in tasks:
                layers: list[LayerText] = []
                for _ in range(lo, hi):
                    length, filament, seconds = _HEADER.unpack(_read_exact(stream, _HEADER.size))
                    if length < 0:
                        import pickle

                        results.put(("error", pickle.loads(_read_exact(stream, -length))))
                        return
                    layers.append((_read_exact(stream, length).decode("ascii"), filament,
                                   seconds))
                results.put(("ok", layers))
    except BaseException as exc:
        results.put(("error", exc))


def _read_exact(stream: BinaryIO, n: int) -> bytes:
    data = stream.read(n)
    if len(data) != n:
        raise RuntimeError("a slicing worker ended before sending its layers")
    return data
