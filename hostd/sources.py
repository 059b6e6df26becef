"""Where a job's G-code comes from: layers sliced just in time, or a G-code file read lazily."""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

import numpy as np

from drivers.protocol import strip_comment
from hostd.schedule import LayerSchedule
from slicer.errors import ModelError
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

# a 10 mm cube: 8 corners, 12 triangles wound outwards
_CUBE_VERTICES = np.array(
    [[x, y, z] for z in (0.0, 10.0) for y in (0.0, 10.0) for x in (0.0, 10.0)]
)
_CUBE_FACES = np.array([
    [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
    [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5],
])


def warm_up(settings: SliceSettings, bed: tuple[float, float, float]) -> None:
    """Slice the first layer of a small cube, once, at start-up.

    The libraries' first use costs (modules loaded on demand, caches filled)
    are paid here, not by the first dropped job while the printer waits.
    """
    plan = SlicePlan.from_mesh(_CUBE_VERTICES, _CUBE_FACES, settings, bed)
    plan.start_gcode()
    plan.layer_gcode(0)


class LayerSource(Protocol):
    """The G-code of one job, in order: a preamble, numbered layers, an ending."""

    layer_count: int

    def preamble(self) -> list[str]:
        """Lines before the first layer streamed (start block, or resume block)."""
        ...

    async def layer(self, index: int) -> list[str]:
        """The lines of layer ``index``; layers are asked for in increasing order."""
        ...

    def ending(self) -> list[str]:
        """Lines after the last layer."""
        ...

    @property
    def ready_ahead(self) -> int:
        """Layers already made and waiting to be streamed."""
        ...

    @property
    def next_unsliced(self) -> int:
        """The first layer whose G-code has not been started yet."""
        ...

    def close(self) -> None:
        """Stop making layers (pending work is dropped)."""
        ...


class SlicedSource:
    """Layers sliced in a thread pool, at most ``depth`` ahead of the one streaming.

    The bound is the backpressure: a layer is submitted only when one is taken,
    so memory holds at most ``depth`` layers however many the model has.
    """

    def __init__(
        self,
        schedule: LayerSchedule,
        first: int,
        depth: int,
        executor: concurrent.futures.Executor,
        resume: bool,
    ) -> None:
        self.schedule = schedule
        self.layer_count = schedule.layer_count
        self.first = first
        self.depth = depth
        self.executor = executor
        self.resume = resume
        self._futures: collections.deque[tuple[int, concurrent.futures.Future[list[str]]]] = (
            collections.deque()
        )
        self._next = first
        self._closed = False
        # until a layer with something to print is made, layers are sliced one at a
        # time: no other layer competes with the one the printer waits for
        self._alone = True
        self._loop = asyncio.get_running_loop()
        self._fill()

    def _fill(self) -> None:
        while not self._closed and len(self._futures) < self.depth and (
            self._next < self.layer_count
        ):
            if self._alone and any(not future.done() for _index, future in self._futures):
                return
            index = self._next
            future = self.executor.submit(self.schedule.layer_gcode, index)
            self._futures.append((index, future))
            self._next += 1
            if self._alone:
                future.add_done_callback(self._made_alone)

    def _made_alone(self, future: concurrent.futures.Future[list[str]]) -> None:
        """(Worker thread) a layer sliced alone is made: go on in the event loop."""
        with contextlib.suppress(RuntimeError):  # the loop has closed
            self._loop.call_soon_threadsafe(self._after_alone, future)

    def _after_alone(self, future: concurrent.futures.Future[list[str]]) -> None:
        if future.cancelled() or future.exception() is not None or len(future.result()) > 1:
            self._alone = False  # more than its ;LAYER line: from now on, the full lookahead
        self._fill()

    def preamble(self) -> list[str]:
        if self.first >= self.layer_count:
            return []  # every layer was printed: only the ending is left
        plan = self.schedule.plan_at(self.first)
        return list(plan.resume_gcode(self.first) if self.resume else plan.start_gcode())

    async def layer(self, index: int) -> list[str]:
        if not self._futures:
            self._fill()
        queued, future = self._futures[0]
        if queued != index:
            raise RuntimeError(f"layer {index} asked for, layer {queued} is next")
        lines = await asyncio.wrap_future(future)
        self._futures.popleft()
        self._fill()
        return lines

    def ending(self) -> list[str]:
        return list(self.schedule.plan_at(self.layer_count - 1).end_gcode())

    @property
    def ready_ahead(self) -> int:
        return sum(1 for _index, future in self._futures if future.done())

    @property
    def next_unsliced(self) -> int:
        return self._next

    def close(self) -> None:
        self._closed = True
        for _index, future in self._futures:
            future.cancel()
        self._futures.clear()


class FileSource:
    """A G-code file printed as is, cut into layers at its ``;LAYER:`` comments."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.layer_count = 0
        preamble: list[str] = []
        commands = 0
        with open(path, encoding="utf-8", errors="replace") as handle:
            for number, line in enumerate(handle, start=1):
                text = line.rstrip("\r\n")
                if not _is_text(text):
                    raise ModelError(f"not a G-code text file: line {number} holds binary data")
                commands += bool(strip_comment(text))
                if line.startswith(";LAYER:"):
                    self.layer_count += 1
                elif self.layer_count == 0:
                    preamble.append(text)
        if not commands:
            raise ModelError("the G-code file has no commands")
        self._preamble = preamble
        self._chunks = self._read_layers()

    def _read_layers(self) -> Iterator[list[str]]:
        with open(self.path, encoding="utf-8", errors="replace") as handle:
            chunk: list[str] | None = None
            for raw in handle:
                line = raw.rstrip("\r\n")
                if line.startswith(";LAYER:"):
                    if chunk is not None:
                        yield chunk
                    chunk = [line]
                elif chunk is not None:
                    chunk.append(line)
            if chunk is not None:
                yield chunk

    def preamble(self) -> list[str]:
        return list(self._preamble)

    async def layer(self, index: int) -> list[str]:
        return next(self._chunks, [])

    def ending(self) -> list[str]:
        return []

    @property
    def ready_ahead(self) -> int:
        return 1

    @property
    def next_unsliced(self) -> int:
        return self.layer_count

    def close(self) -> None:
        self._chunks.close()


def _is_text(line: str) -> bool:
    """True for a line of printable text (tabs allowed): no NUL, control or invalid bytes."""
    return "\ufffd" not in line and line.replace("\t", " ").isprintable()
