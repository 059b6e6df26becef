"""`hostd slice MODEL -o OUT.gcode`: slice a whole model to a file, with a progress bar.

The module stays light, so that ``hostd slice --help`` and a usage error load no
slicer: :func:`run` imports the slicer (numpy, shapely, trimesh) and ``hostd.api``
with the collector paused, and the helpers the other commands share import what
they need when called.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

from hostd.app.cli import UsageError, collector_paused

TYPE_CHECKING = False  # typing itself is not imported to show --help
if TYPE_CHECKING:
    from typing import TextIO

    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

DEFAULT_BED = (220.0, 220.0, 250.0)


def load_settings(config: str | None, assignments: list[str]) -> tuple[SliceSettings, tuple]:
    """Slicing settings and bed size from ``--config FILE`` and ``--set KEY=VALUE`` options.

    The file is checked whole by :func:`hostd.config.load_config` (unknown keys
    refused); its ``[slicing]`` table and ``[printer].bed`` are used, and
    ``--set`` overrides them. Raises UsageError naming the bad key or file.
    """
    from slicer.settings import SettingsError, SliceSettings, parse_assignment

    cfg = None
    if config:
        # the daemon's whole configuration (TOML, link settings) is read only when given
        from hostd.config import ConfigError, load_config

        try:
            cfg = load_config(config)
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
    from slicer.errors import ModelError
    from slicer.plan import SlicePlan
    from slicer.settings import SettingsError

    if not os.path.exists(model):
        raise UsageError(f"{model}: no such file")
    if not _tailoring_asked(model, settings, load):
        # a plain slice: the analysis and the mass search are not even imported
        try:
            return SlicePlan.from_file(model, settings, bed), []
        except ModelError as exc:
            raise UsageError(f"{model}: {exc}") from exc
        except SettingsError as exc:
            raise UsageError(str(exc)) from exc
    from slicer.fea.loadcase import LoadCaseError
    from slicer.fea.tailor import default_cache_dir, tailored_plan

    try:
        plan, tailoring = tailored_plan(model, settings, bed, default_cache_dir(), load)
    except LoadCaseError as exc:  # names its file itself
        raise UsageError(str(exc)) from exc
    except ModelError as exc:
        raise UsageError(f"{model}: {exc}") from exc
    except SettingsError as exc:
        raise UsageError(str(exc)) from exc
    return plan, tailoring.lines()


def _tailoring_asked(model: str, settings: SliceSettings, load: str | None) -> bool:
    """Whether :func:`slicer.fea.tailor.tailored_plan` has anything to do: a load case
    given, set or beside the model, or an equal mass asked for."""
    from slicer.fea import load_path_for

    if load or settings.infill_load:
        return True
    if settings.infill_match_mass_of or settings.infill_target_mass_g > 0:
        return True
    return load_path_for(model).is_file()


class ProgressBar:
    """``hostd slice``'s progress line on a stream (stderr): the label, the one bar
    (:func:`~hostd.app.liveline.fit_bar`) and the layer count on a
    :class:`~hostd.app.liveline.LiveLine`
    (never wider than the terminal, ``columns`` else), redrawn at most 10 times a second."""

    def __init__(self, stream: TextIO, label: str, width: int = 30,
                 columns: int | None = None) -> None:
        from hostd.app.liveline import LiveLine

        self.line = LiveLine(stream, columns)
        self.label = label
        self.width = width
        self.started = time.monotonic()
        self._last = 0.0

    def __call__(self, done: int, total: int) -> None:
        from hostd.app.liveline import fit_bar

        now = time.monotonic()
        if done < total and now - self._last < 0.1:
            return
        self._last = now
        frac = done / total if total else 1.0
        head = f"{self.label} "
        tail = f"{100 * frac:5.1f}% layer {done}/{total} {now - self.started:5.1f}s"
        self.line.draw(head + fit_bar(frac, tail, self.line.width() + 1 - len(head), self.width))
        if done >= total:
            self.line.end()


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


def _jobs(text: str) -> int:
    """``--jobs N``: a whole number of processes, at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: at least 1 process slices")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd slice``."""
    p.add_argument("model", metavar="MODEL")
    p.add_argument("-o", "--output", metavar="OUT.gcode", required=True)
    p.add_argument("--config", metavar="FILE", help="take [slicing] and [printer] from FILE")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="override one slicing setting (repeatable)")
    p.add_argument("--load", metavar="FILE",
                   help="load case (TOML): stress infill from the built-in analysis")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--profile", action="store_true",
                   help="slice in one process and print the time of each stage")
    p.add_argument("--jobs", type=_jobs, metavar="N",
                   help="processes slicing layers (default: the CPUs; 1: this one only)")


def run(args) -> int:
    """Slice ``args.model`` to ``args.output`` and print a summary (and the stage times
    with ``--profile``: one process then, so the stages add up to the whole)."""
    with collector_paused():
        # the slicer (slicer.plan with numpy, shapely, trimesh), the summary's duration
        # and the progress line (not with --quiet), for slicing only
        if not args.quiet:
            import hostd.app.liveline  # noqa: F401  (the progress line's, loaded here)
        from hostd.textforms import duration
        from slicer.output.gcodefile import write_gcode
    return_freed_memory()
    settings, bed = load_settings(args.config, args.set)
    profile = getattr(args, "profile", False)
    with _stage_clock(profile) as clock:
        started = time.monotonic()
        plan, tailoring = load_tailored(args.model, settings, bed, getattr(args, "load", None))
        shown = None if args.quiet else ProgressBar(sys.stderr, "slicing")
        try:
            jobs = getattr(args, "jobs", None)
            summary = write_gcode(plan, args.output, shown, workers=1 if profile else jobs)
        except OSError as exc:
            raise UsageError(f"cannot write {args.output}: {exc.strerror or exc}") from exc
        elapsed = time.monotonic() - started
    print(
        f"{args.output}: {summary.layers} layers, "
        f"filament {summary.filament_mm / 1000.0:.2f} m ({summary.filament_g:.1f} g), "
        f"estimated time {duration(summary.time_s, words=True)}; sliced in {elapsed:.2f} s"
    )
    if plan.body_count > 1:
        print(f"{plan.body_count} objects")
    for line in tailoring:
        print(line)
    for warning in plan.warnings:
        print(f"warning: {warning}")
    if clock is not None:
        from hostd.app.commands.slice_profile import report

        report(clock, elapsed, sys.stdout)
    return 0


@contextmanager
def _stage_clock(on: bool) -> Iterator[object]:
    """The stage timers of ``--profile`` while the block runs (None when off)."""
    if not on:
        yield None
        return
    from hostd.app.commands.slice_profile import profiled

    with profiled() as clock:
        yield clock
