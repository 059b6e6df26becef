"""`hostd slice MODEL -o OUT.gcode`: slice a whole model to a file, with a progress bar."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TextIO

from hostd.cli import UsageError
from hostd.config import ConfigError, load_config
from slicer.annotate import copy_layers, header_extras, object_labels
from slicer.errors import ModelError
from slicer.gcode import GcodeSummary, LayerCode, filament_grams, header_lines
from slicer.plan import SlicePlan
from slicer.settings import SettingsError, SliceSettings, parse_assignment

DEFAULT_BED = (220.0, 220.0, 250.0)


def load_settings(config: str | None, assignments: list[str]) -> tuple[SliceSettings, tuple]:
    """Slicing settings and bed size from ``--config FILE`` and ``--set KEY=VALUE`` options.

    The file is checked whole by :func:`hostd.config.load_config` (unknown keys
    refused); its ``[slicing]`` table and ``[printer].bed`` are used, and
    ``--set`` overrides them. Raises UsageError naming the bad key or file.
    """
    try:
        cfg = load_config(config) if config else None
    except ConfigError as exc:
        raise UsageError(str(exc)) from exc
    settings = cfg.slicing if cfg else SliceSettings()
    bed = tuple(cfg.printer.bed) if cfg else DEFAULT_BED
    try:
        overrides = dict(parse_assignment(a) for a in assignments)
        settings = SliceSettings.from_mapping(overrides, base=settings)
    except SettingsError as exc:
        raise UsageError(str(exc)) from exc
    return settings, bed


def load_plan(model: str, settings: SliceSettings, bed: tuple) -> SlicePlan:
    """The model's plan; a model that cannot be sliced is bad input (UsageError)."""
    return load_tailored(model, settings, bed)[0]


def load_tailored(
    model: str, settings: SliceSettings, bed: tuple, load: str | None = None
) -> tuple[SlicePlan, list[str]]:
    """The model's plan with its load case's analysis (``load``, ``infill.load`` or
    ``NAME.load.toml`` beside the model) and equal mass applied, and the lines
    reporting them. A bad model or load case is bad input (UsageError)."""
    from slicer.fea.loadcase import LoadCaseError
    from slicer.fea.tailor import default_cache_dir, tailored_plan

    if not os.path.exists(model):
        raise UsageError(f"{model}: no such file")
    try:
        plan, tailoring = tailored_plan(model, settings, bed, default_cache_dir(), load)
    except LoadCaseError as exc:  # names its file itself
        raise UsageError(str(exc)) from exc
    except ModelError as exc:
        raise UsageError(f"{model}: {exc}") from exc
    except SettingsError as exc:
        raise UsageError(str(exc)) from exc
    return plan, tailoring.lines()


def iter_layers(plan: SlicePlan, workers: int | None = None) -> Iterator[LayerCode]:
    """Every layer's G-code in order, sliced on a thread pool a bounded window ahead.

    At most ``2 * workers`` layers are held at once, so memory does not grow
    with the layer count. (The daemon's way; ``hostd slice`` itself uses
    :func:`iter_layer_texts`, which also spreads the Python work over cores.)
    """
    from concurrent.futures import ThreadPoolExecutor

    workers = workers or max(1, os.cpu_count() or 1)
    n = plan.layer_count
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="slice") as pool:
        window: deque = deque()
        nxt = 0
        while nxt < n and len(window) < 2 * workers:
            window.append(pool.submit(plan.layer_code, nxt))
            nxt += 1
        while window:
            code = window.popleft().result()
            if nxt < n:
                window.append(pool.submit(plan.layer_code, nxt))
                nxt += 1
            yield code


# the plan a forked worker slices (inherited from the parent at fork time)
_FORKED_PLAN: SlicePlan | None = None
# layers per task: the skin cache's block, so each block is computed by one worker
_CHUNK = 16
# a model with at most this many layers has its first _PROBE layers sliced here
# first, to judge whether forking workers pays for the rest
_SMALL = 4 * _CHUNK
_PROBE = 8
# below this much work (seconds in one process) forking two workers and
# collecting their results (about 20 ms with the import) costs more than it saves
_FORK_WORTH = 0.04
# seconds the outline cut runs alone before the first layers are sliced beside it
_CUT_ALONE = 0.05


def _slice_chunk(lo: int, hi: int) -> list[tuple[str, float, float]]:
    """In a forked worker: layers ``lo..hi-1`` as (text, filament mm, time s)."""
    plan = _FORKED_PLAN
    assert plan is not None
    return [_layer_text(plan, i) for i in range(lo, hi)]


def _layer_text(plan: SlicePlan, i: int) -> tuple[str, float, float]:
    """Layer ``i`` as (G-code text, filament mm, time s)."""
    code = plan.layer_code(i)
    return "\n".join(code.lines) + "\n", code.filament_mm, code.time_s


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
    plan: SlicePlan, workers: int | None = None
) -> Iterator[tuple[str, float, float]]:
    """Every layer as (G-code text, filament mm, time s), in order.

    Most of a layer's work is Python and numpy holding the interpreter lock,
    so threads barely overlap; forked worker processes (which inherit the
    plan, no copy) slice blocks of layers in parallel instead, a bounded
    window ahead of the writer. Without ``fork`` or with one core the layers
    are sliced here, and so are small models: of a model with few layers the
    first ones are sliced here and timed, and workers are forked only when
    the rest would take longer than starting them. The bytes are the same
    either way.
    """
    global _FORKED_PLAN
    workers = workers or max(1, os.cpu_count() or 1)
    n = plan.layer_count
    done = 0
    if workers >= 2 and hasattr(os, "fork") and n <= _SMALL:
        # the bottom layers are solid skin, slower than most: time the later half
        started = time.perf_counter()
        while done < min(_PROBE, n):
            if done == _PROBE // 2:
                started = time.perf_counter()
            yield _layer_text(plan, done)
            done += 1
        timed = done - min(done, _PROBE // 2)
        per_layer = (time.perf_counter() - started) / max(timed, 1)
        if per_layer * (n - done) < _FORK_WORTH:
            workers = 1
    if workers >= 2 and hasattr(os, "fork"):
        import multiprocessing

        if "fork" not in multiprocessing.get_all_start_methods():
            workers = 1
    if workers < 2 or not hasattr(os, "fork"):
        for i in range(done, n):
            yield _layer_text(plan, i)
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
            yield _layer_text(plan, done)
            done += 1
    finally:
        cutter.join()
    _FORKED_PLAN = plan
    try:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            window: deque = deque()
            tasks = _chunks(done, n)
            for lo, hi in tasks:
                window.append(pool.apply_async(_slice_chunk, (lo, hi)))
                if len(window) >= 2 * workers:
                    break
            while window:
                chunk = window.popleft().get()
                task = next(tasks, None)
                if task is not None:
                    window.append(pool.apply_async(_slice_chunk, task))
                yield from chunk
    finally:
        _FORKED_PLAN = None


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
        for i, (text, layer_filament, layer_time) in enumerate(iter_layer_texts(plan, workers)):
            if labels is not None:
                text = "\n".join(labels.label_layer(i, text.splitlines())) + "\n"
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


class ProgressBar:
    """A one-line text progress bar on a stream (stderr), redrawn at most 10 times a second."""

    def __init__(self, stream: TextIO, label: str, width: int = 30) -> None:
        self.stream = stream
        self.label = label
        self.width = width
        self.started = time.monotonic()
        self._last = 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if done < total and now - self._last < 0.1:
            return
        self._last = now
        frac = done / total if total else 1.0
        filled = round(frac * self.width)
        bar = "#" * filled + "-" * (self.width - filled)
        self.stream.write(
            f"\r{self.label} [{bar}] {100 * frac:5.1f}% layer {done}/{total} "
            f"{now - self.started:5.1f}s"
        )
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()


def format_duration(seconds: float) -> str:
    """``1h 02m 03s`` style."""
    s = round(seconds)
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h {m:02d}m {s:02d}s" if h else f"{m}m {s:02d}s"


def return_freed_memory() -> None:
    """Make glibc give freed big arrays back to the system at once (Linux only).

    By default glibc raises its mmap threshold after the first big free, so
    later arrays come from a heap that never shrinks; pinning the thresholds
    keeps peak RSS at what the slicer really holds. The mmap threshold is
    1 MiB, not lower: every array above it is mapped afresh and its pages
    faulted in and zeroed on first use, which at 256 KiB cost a big model's
    load and cut about a tenth of their time for no lower peak. A no-op
    elsewhere.
    """
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return
    m_trim_threshold, m_mmap_threshold = -1, -3
    libc.mallopt(m_mmap_threshold, 1024 * 1024)
    libc.mallopt(m_trim_threshold, 1024 * 1024)


def run(args) -> int:
    """Slice ``args.model`` to ``args.output`` and print a summary (and the stage times
    with ``--profile``: one process then, so the stages add up to the whole)."""
    return_freed_memory()
    settings, bed = load_settings(args.config, args.set)
    profile = getattr(args, "profile", False)
    with _stage_clock(profile) as clock:
        started = time.monotonic()
        plan, tailoring = load_tailored(args.model, settings, bed, getattr(args, "load", None))
        bar = None if args.quiet else ProgressBar(sys.stderr, "slicing")
        try:
            summary = write_gcode(plan, args.output, bar, workers=1 if profile else None)
        except OSError as exc:
            raise UsageError(f"cannot write {args.output}: {exc.strerror or exc}") from exc
        elapsed = time.monotonic() - started
    print(
        f"{args.output}: {summary.layers} layers, "
        f"filament {summary.filament_mm / 1000.0:.2f} m ({summary.filament_g:.1f} g), "
        f"estimated time {format_duration(summary.time_s)}; sliced in {elapsed:.2f} s"
    )
    if plan.body_count > 1:
        print(f"{plan.body_count} objects")
    for line in tailoring:
        print(line)
    for warning in plan.warnings:
        print(f"warning: {warning}")
    if clock is not None:
        from hostd.commands.slice_profile import report

        report(clock, elapsed, sys.stdout)
    return 0


@contextmanager
def _stage_clock(on: bool) -> Iterator[object]:
    """The stage timers of ``--profile`` while the block runs (None when off)."""
    if not on:
        yield None
        return
    from hostd.commands.slice_profile import profiled

    with profiled() as clock:
        yield clock
