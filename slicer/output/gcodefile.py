"""Writing a whole G-code file: every layer sliced a bounded window ahead, header first."""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from slicer.output.annotate import copy_layers, header_extras, object_labels
from slicer.output.gcode import GcodeSummary, filament_grams, header_lines
from slicer.output.labels import ObjectLabels
from slicer.pipeline import LayerWindow, in_blocks
from slicer.plan import SlicePlan

# layers per task: the skin cache's block, so each block is computed by one worker
_CHUNK = 16
# the first _PROBE layers are sliced here and timed, to judge whether forking
# workers pays for the rest
_PROBE = 8
# below this much work left (seconds in one process) forking workers costs more
# than it saves: the outlines are cut whole first, and the workers redo some
# work per process (copied pages, skin blocks shared by two tasks), about a
# fifth more CPU time in all. On a free second core it pays from about 0.05 s:
# the bracket's first layers (a plate) predicted 0.10-0.14 s for the rest, its
# walls took 0.30 s, and forked it finished in 0.34 s instead of 0.45 s; models
# with less left were as fast either way (medians of 7, bench/.cache/corpus)
_FORK_WORTH = 0.05
# a model whose outline cut is estimated to take this long or more (s) is forked for
# at once: its outlines are cut before forking and every layer goes to the workers,
# none is timed here first. The lightest model above it, the panel clip (0.02 s, 50
# layers), has 0.11 s of layers left after the first 8: every such model forks
# anyway, and timing 8 layers here first left the second core idle for them (the
# lower idler: 66 ms of CPU in this process before the workers began, 24 ms now)
_AT_ONCE_WORTH = 0.015
# an outline cut estimated to take this long or more (s) is made on two cores: the
# top blocks in a forked process (sent back as WKB), the bottom ones here. Cut
# alone, the 158-layer lattice's 0.126 s cut took 0.090 s in two processes; below
# it the fork, the WKB sent back and the wait cost what the overlap gains: the panel
# clip (0.02 s) reached its workers after as much CPU time here either way (23 and
# 22 ms, medians of 10) and spent 12 ms more CPU in all with its cut sent away; the
# lower idler (0.07 s on a loaded machine) 27 ms against 37 ms here. Its estimate
# is often under 0.05 s (0.026-0.039 s at load 3, lower when the machine is quiet):
# its cut then stayed here, the second core idle for it
_CUT_AWAY_WORTH = 0.02
# tasks (of _CHUNK layers) a forked worker may have made or in hand beyond the one
# being written: the window's depth in layers is _AHEAD * workers * _CHUNK
_AHEAD = 2


def _layer_texts(
    plan: SlicePlan, lo: int, hi: int, labels: ObjectLabels | None = None
) -> list[tuple[str, float, float]]:
    """Layers ``lo .. hi - 1`` as (G-code text, filament mm, time s), made together
    (:meth:`~slicer.plan.SlicePlan.layer_codes`), their bodies' moves bracketed when
    ``labels`` are given."""
    out = []
    for i, code in enumerate(plan.layer_codes(lo, hi), start=lo):
        lines = code.lines if labels is None else labels.label_layer(i, code.lines, code.spans)
        out.append(("\n".join(lines) + "\n", code.filament_mm, code.time_s))
    return out


def _layer_text(
    plan: SlicePlan, i: int, labels: ObjectLabels | None = None
) -> tuple[str, float, float]:
    """Layer ``i`` as (G-code text, filament mm, time s), its bodies' moves bracketed
    when ``labels`` are given."""
    return _layer_texts(plan, i, i + 1, labels)[0]


def _chunks(lo: int, n: int) -> Iterator[tuple[int, int]]:
    """Tasks ``[a, b)`` covering layers ``lo..n-1``: the skin cache's blocks.

    The first 16 layers come as 0-3, 4-7 and 8-15 (unions of the cache's
    growing first blocks), so both workers start at once on small tasks;
    then one task per 16-layer block.
    """
    for a, b in ((0, 4), (4, 8), (8, _CHUNK)):
        if b > lo and a < n:
            yield max(a, lo), min(b, n)
    if lo > _CHUNK and lo % _CHUNK:  # the rest of a block begun here
        yield lo, min(n, lo - lo % _CHUNK + _CHUNK)
    for a in range(max(_CHUNK, -(-lo // _CHUNK) * _CHUNK), n, _CHUNK):
        yield a, min(n, a + _CHUNK)


def _whole_blocks(n: int) -> Iterator[tuple[int, int]]:
    """Tasks ``[a, b)`` covering layers ``0..n-1``, one per skin cache block of
    ``_CHUNK`` layers, for workers forked before any layer is made.

    A layer's skins and islands look at the layers around it, so two tasks
    made in different processes each solve what their edge shares; small first
    tasks (:func:`_chunks`) bring the first layer sooner but add two such edges.
    The whole file waits for the last layer, not the first: the lower idler's
    58 layers are four tasks instead of six.
    """
    for a in range(0, n, _CHUNK):
        yield a, min(n, a + _CHUNK)


class Aside:
    """Lines the layers do not need (the file's header extras), made by ``make`` in a
    forked worker once every layer's task is handed out: the first worker left
    without a layer takes it, while the other still slices. ``lines`` holds them
    once made there (None when no worker was forked: make them here then)."""

    def __init__(self, make: Callable[[], list[str]]) -> None:
        self.make = make
        self.lines: list[str] | None = None


def iter_layer_texts(
    plan: SlicePlan, workers: int | None = None, labels: ObjectLabels | None = None,
    aside: Aside | None = None,
) -> Iterator[tuple[str, float, float]]:
    """Every layer as (G-code text, filament mm, time s), in order, labelled by
    ``labels`` when given (in the workers, so the labelling is spread over cores too).

    The layers come out of :class:`~slicer.pipeline.LayerWindow`, the bounded
    window the daemon and ``hostd print`` take layers from, with one engine or
    another, a task of layers (:func:`_chunks`) at a time: a task's G-code is made
    in one pass, cheaper per layer than layer by layer. Most of a layer's work is
    Python and numpy holding the interpreter lock, so threads barely overlap:
    forked worker processes (:class:`~slicer.forkslice.ForkedLayers`, which
    inherit the plan, no copy) slice tasks in parallel instead, at most
    ``_AHEAD * workers * _CHUNK`` layers ahead of the writer. Without ``fork``
    or with one core the layers are sliced in this thread, and so are small
    models: unless the outlines alone are heavy (:data:`_AT_ONCE_WORTH`, then
    every layer goes to the workers at once), the first layers are sliced here
    and timed, and workers are forked only when the rest would take long enough
    to gain (:data:`_FORK_WORTH`).
    The bytes are the same either way. ``aside``, when given and workers are
    forked, is made by a worker after the layers' tasks (:class:`Aside`): made in
    this process while the workers sliced, it took the CPU time of both cores'
    layers (3 processes on 2 cores), where at the end one worker waits for the
    other's last task.
    """
    workers = workers or max(1, os.cpu_count() or 1)
    n = plan.layer_count

    def make(lo: int, hi: int) -> list[tuple[str, float, float]]:
        return _layer_texts(plan, lo, hi, labels)

    fork = workers >= 2 and hasattr(os, "fork")
    estimate = plan.cut_estimate() if fork else 0.0
    if fork and estimate >= _AT_ONCE_WORTH:
        # a model whose outlines take this long to cut has more than enough layers to
        # gain from workers: no layer is timed here, the outlines are cut at once (on
        # two cores when heavy: from the top down in a forked process, from the bottom
        # up here) and every layer goes to the workers, so both cores work from the start
        away = plan.cut_away() if estimate >= _CUT_AWAY_WORTH else None
        if away is not None:
            try:
                away.meet()
            finally:
                away.close()
        plan.cut_all()
        yield from _forked(plan, make, 0, n, workers, aside)
        return
    probe = min(_PROBE, n) if fork else 0
    tasks = list(_chunks(0, n))
    if fork:  # the layers timed here (0-3 and 4-7)
        tasks = [(lo, hi) for lo, hi in tasks if hi <= probe]
    here: LayerWindow[tuple[str, float, float]] = LayerWindow(
        in_blocks(make, tasks), n, depth=1)
    try:
        if fork:
            # the bottom layers are solid skin, slower than most: time the later half
            started = time.perf_counter()
            while here.taken < probe:
                if here.taken == _PROBE // 2:
                    started = time.perf_counter()
                yield here.take()
            timed = here.taken - min(here.taken, _PROBE // 2)
            per_layer = (time.perf_counter() - started) / max(timed, 1)
            fork = per_layer * (n - here.taken) >= _FORK_WORTH
        if not fork:
            if probe and here.taken < n:  # the rest, task by task
                here.close()
                here = LayerWindow(in_blocks(make, list(_chunks(here.taken, n))), n,
                                   depth=1, first=here.taken)
            yield from here
            return
        # the outlines are all cut before forking, so the workers inherit them instead
        # of each cutting the blocks its layers and their skins need
        plan.cut_all()
    finally:
        here.close()
    yield from _forked(plan, make, here.taken, n, workers, aside)


def _forked(
    plan: SlicePlan, make: Callable[[int, int], list[tuple[str, float, float]]],
    done: int, n: int, workers: int, aside: Aside | None,
) -> Iterator[tuple[str, float, float]]:
    """Layers ``done..n-1`` made by ``workers`` forked processes, a task at a time,
    in order; ``aside``, when given, is a task of its own (numbered ``n``), handed
    out after the layers' first window of tasks, and its lines are read back
    after the last layer."""
    from slicer.forkslice import ForkedLayers

    tasks = list(_chunks(done, n)) if done else list(_whole_blocks(n))

    def task(lo: int, hi: int) -> list[tuple[str, float, float]]:
        if lo == n and aside is not None:  # one text: the lines, each ended by a newline
            return [("".join(line + "\n" for line in aside.make()), 0.0, 0.0)]
        return make(lo, hi)

    if aside is not None:
        tasks.append((n, n + 1))
    with ForkedLayers(task, tasks, workers) as engine:
        window: LayerWindow[tuple[str, float, float]] = LayerWindow(
            engine.submit, n, depth=_AHEAD * workers * _CHUNK, first=done
        )
        try:
            made_aside = engine.submit(n) if aside is not None else None
            yield from window
            if made_aside is not None and aside is not None:
                text = made_aside.result()[0]
                aside.lines = text.split("\n")[:-1]  # the same lines, written the same
        finally:
            window.close()


def write_gcode(
    plan: SlicePlan,
    out: str | os.PathLike[str],
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
) -> GcodeSummary:
    """Write the whole program to ``out`` (header, start, layers, end); return its totals.

    Layers are streamed to a temporary file beside ``out``; the header, which
    needs the totals, is written first into the final file, then the body is
    copied after it and the result renamed into place. An ``out`` that is not a
    regular file (``/dev/null``, ``/dev/stdout``, a named pipe) is written in
    place: renaming a file onto it would replace the device or pipe.
    """
    out = Path(out)
    in_place = out.exists() and not out.is_file()
    directory = out.parent if str(out.parent) else Path(".")
    filament = 0.0
    seconds = 0.0
    n = plan.layer_count
    labels = object_labels(plan, plan.settings)
    lengths: list[int] = []
    times: list[float] = []
    # thumbnails and objects' definitions: the outlines only
    extras = Aside(lambda: header_extras(plan, plan.settings, labels))

    with tempfile.TemporaryFile("w+", encoding="ascii", newline="\n") as body:
        layers = iter_layer_texts(plan, workers, labels, aside=extras)
        for i, (text, layer_filament, layer_time) in enumerate(layers):
            body.write(text)
            lengths.append(len(text))
            times.append(layer_time)
            filament += layer_filament
            seconds += layer_time
            if progress:
                progress(i + 1, n)
        body.write("\n".join(plan.end_gcode()) + "\n")
        summary = GcodeSummary(n, filament, filament_grams(filament, plan.settings), seconds)
        body.seek(0)
        if extras.lines is None:  # no workers were forked
            extras.lines = extras.make()
        head = "\n".join(header_lines(summary, plan.settings)) + "\n"
        head += "".join(line + "\n" for line in extras.lines)
        head += "\n".join(plan.start_gcode()) + "\n"
        if in_place:
            with open(out, "w", encoding="ascii", newline="\n") as fh:
                fh.write(head)
                copy_layers(fh, body, lengths, times)
            return summary
        fd, tmp = tempfile.mkstemp(prefix=".hostd-", suffix=".gcode", dir=directory)
        try:
            with os.fdopen(fd, "w", encoding="ascii", newline="\n") as fh:
                fh.write(head)
                copy_layers(fh, body, lengths, times)
            os.replace(tmp, out)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    return summary
