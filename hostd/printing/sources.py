"""Where a job's G-code comes from: layers sliced just in time, or a G-code file read lazily."""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Protocol

import numpy as np

from drivers.link.protocol import strip_comment
from hostd.jobs.schedule import LayerSchedule
from slicer.errors import ModelError
from slicer.output.entry import last_xy
from slicer.pipeline import LayerWindow
from slicer.plan import SlicePlan, load_on_demand_modules
from slicer.settings import SliceSettings

KEPT_TAKEN = 3  # layers taken (streamed) whose lines are kept for views

# a 10 mm cube: 8 corners, 12 triangles wound outwards
_CUBE_VERTICES = np.array(
    [[x, y, z] for z in (0.0, 10.0) for y in (0.0, 10.0) for x in (0.0, 10.0)]
)
_CUBE_FACES = np.array([
    [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
    [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5],
])


def warm_up(settings: SliceSettings, bed: tuple[float, float, float]) -> None:
    """Slice the first layer of a small cube, once, at start-up, then load the modules
    that other models' layers load on first use.

    The libraries' first use costs (modules loaded on demand, caches filled)
    are paid here, not by the first dropped job while the printer waits.
    """
    plan = SlicePlan.from_mesh(_CUBE_VERTICES, _CUBE_FACES, settings, bed)
    plan.start_gcode()
    plan.layer_gcode(0)
    load_on_demand_modules()


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

    def started(self) -> None:
        """The printer acknowledged the job's first extruding move: work held back so
        as not to delay it may begin."""
        ...

    @property
    def ready_ahead(self) -> int:
        """Layers already made and waiting to be streamed."""
        ...

    def held(self, index: int) -> list[str] | None:
        """Layer ``index``'s lines if they are made already (streamed lately, or made
        ahead and waiting), else None; never waits and changes nothing."""
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

    The window is :class:`slicer.pipeline.LayerWindow`, the one bounded-lookahead
    iterator `hostd print FILE.stl` (also on a thread pool) and `hostd slice` (on
    forked workers, :class:`slicer.forkslice.ForkedLayers`) take their layers from:
    a layer is submitted only when one is taken, so memory holds at most ``depth``
    layers however many the model has. Until a layer with
    something to print is made, layers are sliced one at a time: no other layer
    competes with the one the printer waits for. The layers after the first are
    then held back until the printer acknowledged the first extruding move
    (:meth:`started`) or the next layer is asked for: slicing them in the pool's
    threads would take the interpreter from the lines the printer waits for.
    """

    def __init__(
        self,
        schedule: LayerSchedule,
        first: int,
        depth: int,
        executor: concurrent.futures.Executor,
        resume: bool,
        on_started: Callable[[], None] | None = None,
    ) -> None:
        """``on_started``: called once from :meth:`started`, for other work held back."""
        self.schedule = schedule
        self._on_started = on_started
        self.layer_count = schedule.layer_count
        self.first = first
        self.resume = resume
        self._executor = executor
        self._lock = threading.Lock()
        # layers asked for while held back, with the futures the window was given
        self._held: list[tuple[int, concurrent.futures.Future[list[str]]]] | None = []
        # layers handed to the pool and not finished (see settled())
        self._slicing: set[concurrent.futures.Future[list[str]]] = set()
        self._window: LayerWindow[list[str]] = LayerWindow(
            self._submit, self.layer_count, depth, first=first, alone=True,
            worth=lambda lines: len(lines) > 1,  # more than its ;LAYER line
        )
        self._at: np.ndarray | None = None  # where the nozzle is after the last layer taken
        # the last layers taken, as streamed (for views of the layer printing)
        self._taken: dict[int, list[str]] = {}

    def preamble(self) -> list[str]:
        if self.first >= self.layer_count:
            return []  # every layer was printed: only the ending is left
        plan = self.schedule.plan_at(self.first)
        return list(plan.resume_gcode(self.first) if self.resume else plan.start_gcode())

    def _submit(self, index: int) -> concurrent.futures.Future[list[str]]:
        """Slice layer ``index`` in the pool, or hold it back (see the class)."""
        with self._lock:
            if self._held is not None and index != self.first:
                waiting: concurrent.futures.Future[list[str]] = concurrent.futures.Future()
                self._held.append((index, waiting))
                return waiting
        return self._track(self._executor.submit(self.schedule.layer_gcode, index))

    def _track(
        self, future: concurrent.futures.Future[list[str]]
    ) -> concurrent.futures.Future[list[str]]:
        """Count ``future`` among the layers being sliced until it is done."""
        with self._lock:
            self._slicing.add(future)
        future.add_done_callback(self._untrack)
        return future

    def _untrack(self, future: concurrent.futures.Future[list[str]]) -> None:
        with self._lock:
            self._slicing.discard(future)

    async def settled(self) -> None:
        """Wait until no layer of this source is being sliced any longer (after
        :meth:`close`: the ones a worker had begun finish), so that what they made is
        freed with the job (a cancelled job's layers in flight)."""
        with self._lock:
            slicing = list(self._slicing)
        if slicing:
            await asyncio.gather(*(asyncio.wrap_future(f) for f in slicing),
                                 return_exceptions=True)

    def started(self) -> None:
        with self._lock:
            held, self._held = self._held, None
            then, self._on_started = self._on_started, None
        if then is not None:
            then()
        for index, waiting in held or ():
            if not waiting.set_running_or_notify_cancel():
                continue  # dropped by close()
            try:
                made = self._track(self._executor.submit(self.schedule.layer_gcode, index))
            except RuntimeError as exc:  # the pool is shutting down
                waiting.set_exception(exc)
                continue
            made.add_done_callback(lambda done, into=waiting: _pass_on(done, into))

    async def layer(self, index: int) -> list[str]:
        if index != self.first:
            self.started()  # the first layer is streamed: hold nothing back any longer
        lines = await self._window.take_async(index)
        if self.schedule.excluded_at(index) and index > 0:
            # the first travel goes around the cancelled bodies from where the layer
            # before ended (after a resume, that layer is sliced again to know where)
            if self._at is None and index == self.first:
                self._at = await asyncio.to_thread(self.schedule.came_from, index - 1)
            lines = await asyncio.to_thread(self.schedule.entered, index, lines, self._at)
        end = last_xy(lines)
        self._at = end if end is not None else self._at
        self._taken[index] = lines
        for old in [i for i in self._taken if i <= index - KEPT_TAKEN]:
            del self._taken[old]
        return lines

    def held(self, index: int) -> list[str] | None:
        taken = self._taken.get(index)
        return taken if taken is not None else self._window.made(index)

    def ending(self) -> list[str]:
        return list(self.schedule.plan_at(self.layer_count - 1).end_gcode())

    @property
    def ready_ahead(self) -> int:
        return self._window.ready_ahead

    @property
    def next_unsliced(self) -> int:
        return self._window.next_unsliced

    def close(self) -> None:
        self._window.close()


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

    def started(self) -> None:
        pass

    def held(self, index: int) -> list[str] | None:
        return None

    @property
    def ready_ahead(self) -> int:
        return 1

    @property
    def next_unsliced(self) -> int:
        return self.layer_count

    def close(self) -> None:
        self._chunks.close()


def _pass_on(
    done: concurrent.futures.Future[list[str]], into: concurrent.futures.Future[list[str]]
) -> None:
    """Give ``into`` the outcome of ``done``."""
    if done.cancelled():
        into.set_exception(concurrent.futures.CancelledError())
    elif done.exception() is not None:
        into.set_exception(done.exception())
    else:
        into.set_result(done.result())


def _is_text(line: str) -> bool:
    """True for a line of printable text (tabs allowed): no NUL, control or invalid bytes."""
    return "\ufffd" not in line and line.replace("\t", " ").isprintable()
