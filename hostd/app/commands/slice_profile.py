"""`hostd slice --profile`: the time of each slicing stage, so that a slow stage shows at once.

The stages' entry points are wrapped with timers for the run (one process, no
workers, so the stages add up to the whole); each timer counts its own time
only, less the stages it calls (a skin block that cuts outlines counts the cut
under outlines). Heavy imports made inside a stage count to that stage.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

# (stage, module, attribute): the functions timed, in the order stages are printed
STAGES: tuple[tuple[str, str, str], ...] = (
    ("read", "slicer.plan", "read_stl"),
    ("check and repair", "slicer.plan", "prepare"),
    ("layer heights and face buckets", "slicer.plan", "_cut_model"),
    ("outlines", "slicer.input.lazycut", "LazyOutlines._cut"),
    ("skins", "slicer.paths.skins", "SkinCache.get"),
    ("walls", "slicer.plan", "layer_paths_many"),
    ("walls", "slicer.paths.islands", "widen_thin_walls"),
    ("walls", "slicer.paths.loops", "wall_loops"),
    ("infill", "slicer.paths.layer", "_solid_small_regions"),
    ("infill", "slicer.paths.layer", "_stacks_many"),
    ("infill", "slicer.paths.layer", "_sparse_lines"),
    ("ordering", "slicer.paths.layer", "_island_order"),
    ("ordering", "slicer.paths.loops", "order_loops"),
    ("ordering", "slicer.paths.order", "chord_stacks"),
    ("ordering", "slicer.paths.order", "walk_stacks"),
    ("ordering", "slicer.paths.order", "order_open_paths"),
    ("ordering", "slicer.paths.order", "join_runs"),
    ("G-code", "slicer.output.gcode", "layer_codes"),
)


class StageClock:
    """Exclusive time per stage (s): nested stages are subtracted from their caller."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._stack: list[list[float]] = []  # [start, time spent in nested stages]

    def wrap(self, stage: str, fn: Callable) -> Callable:
        """``fn`` timed under ``stage``."""

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            frame = [time.perf_counter(), 0.0]
            self._stack.append(frame)
            try:
                return fn(*args, **kwargs)
            finally:
                self._stack.pop()
                spent = time.perf_counter() - frame[0]
                self.seconds[stage] = self.seconds.get(stage, 0.0) + spent - frame[1]
                self.calls[stage] = self.calls.get(stage, 0) + 1
                if self._stack:
                    self._stack[-1][1] += spent

        return timed


@contextmanager
def profiled() -> Iterator[StageClock]:
    """Time every stage of :data:`STAGES` while the block runs; the originals come back after."""
    import importlib

    clock = StageClock()
    undo: list[tuple[object, str, object]] = []
    try:
        for stage, module, attr in STAGES:
            owner: object = importlib.import_module(module)
            *path, name = attr.split(".")
            for part in path:
                owner = getattr(owner, part)
            original = getattr(owner, name)
            undo.append((owner, name, original))
            setattr(owner, name, clock.wrap(stage, original))
        yield clock
    finally:
        for owner, name, original in reversed(undo):
            setattr(owner, name, original)


def report(clock: StageClock, total_s: float, stream: TextIO) -> None:
    """Print the stages, their share of ``total_s`` and what is left over (writing, start-up)."""
    order = list(dict.fromkeys(stage for stage, _, _ in STAGES))
    stream.write(f"{'stage':32s} {'seconds':>8s} {'share':>6s} {'calls':>6s}\n")
    accounted = 0.0
    for stage in order:
        s = clock.seconds.get(stage, 0.0)
        accounted += s
        stream.write(f"{stage:32s} {s:8.3f} {100 * s / total_s if total_s else 0:5.1f}% "
                     f"{clock.calls.get(stage, 0):6d}\n")
    other = max(0.0, total_s - accounted)
    stream.write(f"{'other (writing, bookkeeping)':32s} {other:8.3f} "
                 f"{100 * other / total_s if total_s else 0:5.1f}%\n")
    stream.write(f"{'total':32s} {total_s:8.3f}\n")
