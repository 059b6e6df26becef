"""Writing a whole G-code file: every layer sliced a bounded window ahead, header first."""

from __future__ import annotations

import os
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from slicer.annotate import copy_layers, header_extras, object_labels
from slicer.gcode import GcodeSummary, LayerCode, filament_grams, header_lines
from slicer.labels import ObjectLabels
from slicer.plan import SlicePlan


def iter_layers(plan: SlicePlan, workers: int | None = None) -> Iterator[LayerCode]:
    """Every layer's G-code in order, sliced on a thread pool a bounded window ahead.

    At most ``2 * workers`` layers are held at once (a :class:`LayerWindow`, as in
    the daemon), so memory does not grow with the layer count. (``hostd slice``
    itself uses :func:`iter_layer_texts`, which also spreads the Python work over
    cores.)
    """
    import concurrent.futures

    from slicer.pipeline import LayerWindow

    workers = workers or max(1, os.cpu_count() or 1)
    with concurrent.futures.ThreadPoolExecutor(workers, thread_name_prefix="slice") as pool:
        window: LayerWindow[LayerCode] = LayerWindow(
            lambda index: pool.submit(plan.layer_code, index), plan.layer_count, 2 * workers
        )
        try:
            yield from window
        finally:
            window.close()


# layers per task: the skin cache's block, so each block is computed by one worker
_CHUNK = 16
# the first _PROBE layers are sliced here and timed, to judge whether forking
# workers pays for the rest
_PROBE = 8
# below this much work left (seconds in one process) forking workers costs more
# than it saves: the outlines are cut whole first, and the workers redo some
# work per process (copied pages, skin blocks shared by two tasks), about a
# fifth more CPU time in all (a 100-layer cube: 0.09 s of layers here, 0.14 s
# in two workers, later in wall time; the bracket: 1.2-1.6 s against 1.5-1.9 s)
_FORK_WORTH = 0.15
# seconds the outline cut runs alone before the first layers are sliced beside it
_CUT_ALONE = 0.05


def _layer_text(
    plan: SlicePlan, i: int, labels: ObjectLabels | None = None
) -> tuple[str, float, float]:
    """Layer ``i`` as (G-code text, filament mm, time s), its bodies' moves bracketed
    when ``labels`` are given."""
    code = plan.layer_code(i)
    lines = code.lines if labels is None else labels.label_layer(i, code.lines, code.extrusions)
    return "\n".join(lines) + "\n", code.filament_mm, code.time_s


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


def iter_layer_texts(
    plan: SlicePlan, workers: int | None = None, labels: ObjectLabels | None = None
) -> Iterator[tuple[str, float, float]]:
    """Every layer as (G-code text, filament mm, time s), in order, labelled by
    ``labels`` when given (in the workers, so the labelling is spread over cores too).

    Most of a layer's work is Python and numpy holding the interpreter lock,
    so threads barely overlap; forked worker processes (which inherit the
    plan, no copy) slice blocks of layers in parallel instead, a bounded
    window ahead of the writer. Without ``fork`` or with one core the layers
    are sliced here, and so are small models: the first layers are sliced
    here and timed, and workers are forked only when the rest would take
    long enough to gain (:data:`_FORK_WORTH`). The bytes are the same either
    way.
    """
    workers = workers or max(1, os.cpu_count() or 1)
    n = plan.layer_count
    done = 0
    if workers >= 2 and hasattr(os, "fork"):
        # the bottom layers are solid skin, slower than most: time the later half
        started = time.perf_counter()
        while done < min(_PROBE, n):
            if done == _PROBE // 2:
                started = time.perf_counter()
            yield _layer_text(plan, done, labels)
            done += 1
        timed = done - min(done, _PROBE // 2)
        per_layer = (time.perf_counter() - started) / max(timed, 1)
        if per_layer * (n - done) < _FORK_WORTH:
            workers = 1
    if workers < 2 or not hasattr(os, "fork"):
        for i in range(done, n):
            yield _layer_text(plan, i, labels)
        return
    # outlines are cut lazily; cut them all once here so the workers inherit
    # them instead of each cutting the blocks its layers and their skins need;
    # the first layers are sliced here meanwhile (they need the first blocks only)
    cutter = threading.Thread(target=plan.cut_all, kwargs={"threads": workers}, name="cut")
    cutter.start()
    try:
        # a short cut is left alone: layer work here would hold the interpreter
        # lock the cutting threads need between their array operations
        cutter.join(_CUT_ALONE)
        while done < n and cutter.is_alive():
            yield _layer_text(plan, done, labels)
            done += 1
    finally:
        cutter.join()
    from slicer.forkslice import forked_layers

    yield from forked_layers(
        lambda i: _layer_text(plan, i, labels), list(_chunks(done, n)), workers
    )


def write_gcode(
    plan: SlicePlan,
    out: str | os.PathLike[str],
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
) -> GcodeSummary:
    """Write the whole program to ``out`` (header, start, layers, end); return its totals.

    Layers are streamed to a temporary file beside ``out``; the header, which
    needs the totals, is written first into the final file, then the body is
    copied after it and the result renamed into place.
    """
    out = Path(out)
    directory = out.parent if str(out.parent) else Path(".")
    filament = 0.0
    seconds = 0.0
    n = plan.layer_count
    labels = object_labels(plan, plan.settings)
    lengths: list[int] = []
    times: list[float] = []
    with tempfile.TemporaryFile("w+", encoding="ascii", newline="\n") as body:
        layers = iter_layer_texts(plan, workers, labels)
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
        fd, tmp = tempfile.mkstemp(prefix=".hostd-", suffix=".gcode", dir=directory)
        try:
            with os.fdopen(fd, "w", encoding="ascii", newline="\n") as fh:
                fh.write("\n".join(header_lines(summary, plan.settings)) + "\n")
                extras = header_extras(plan, plan.settings, labels)
                fh.write("".join(line + "\n" for line in extras))
                fh.write("\n".join(plan.start_gcode()) + "\n")
                copy_layers(fh, body, lengths, times)
            os.replace(tmp, out)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    return summary
