"""What a written G-code file adds for other hosts: thumbnails, object labels, M73 progress."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, TextIO

from slicer.output.gcode import summarize
from slicer.output.labels import ObjectLabels, progress_line
from slicer.output.thumbnails import thumbnail_lines
from slicer.settings import SliceSettings

if TYPE_CHECKING:
    from slicer.plan import SlicePlan

# lines that are there for other hosts and printer screens, not part of any layer's own code
ANNOTATIONS = ("M73 ", "M486 ", "EXCLUDE_OBJECT_")


def is_annotation(line: str) -> bool:
    """True for a line this module adds (``M73``, ``M486``, ``EXCLUDE_OBJECT_...``)."""
    return line.startswith(ANNOTATIONS)


def object_labels(plan: SlicePlan, settings: SliceSettings) -> ObjectLabels | None:
    """Labels for a plan of two bodies or more with ``gcode.labels`` on, else None."""
    return ObjectLabels(plan) if settings.gcode_labels and plan.body_count >= 2 else None


def header_extras(plan: SlicePlan, settings: SliceSettings, labels: ObjectLabels | None
                  ) -> list[str]:
    """The thumbnails of ``gcode.thumbnails`` and the objects' definitions, for the header."""
    lines = thumbnail_lines(plan, settings.gcode_thumbnails)
    if labels is not None:
        lines += labels.define_lines()
    return lines


def with_progress(text: str, before_s: float, total_s: float) -> str:
    """A layer's text (starting with its ``;LAYER:`` line) with ``M73`` after that line."""
    head, _newline, rest = text.partition("\n")
    return f"{head}\n{progress_line(before_s, total_s)}\n{rest}"


def copy_layers(out: TextIO, body: TextIO, lengths: list[int], times: list[float]) -> None:
    """Copy ``body`` (layers of ``lengths`` characters, then the ending) to ``out``, adding
    each layer's ``M73`` from ``times`` (s) and ``M73 P100 R0`` before the ending."""
    total = sum(times)
    before = 0.0
    for length, seconds in zip(lengths, times, strict=True):
        out.write(with_progress(body.read(length), before, total))
        before += seconds
    out.write(progress_line(total, total) + "\n")
    shutil.copyfileobj(body, out, 1 << 20)


def _split(lines: Iterable[str]) -> Iterator[tuple[str, list[str]]]:
    """A program's lines in parts: ("pre", ...), ("layer", ...) each, ("end", ...)."""
    kind, part = "pre", list[str]()
    for line in lines:
        if line.startswith(";LAYER:") or (line.startswith(";END") and kind != "end"):
            if part:
                yield kind, part
            kind, part = ("layer" if line.startswith(";LAYER:") else "end"), []
        part.append(line)
    if part:
        yield kind, part


def layer_times(parts: Iterable[tuple[str, list[str]]], settings: SliceSettings) -> list[float]:
    """Each layer's time (s) by :func:`slicer.output.gcode.summarize`, starting where the part
    before it left the nozzle (relative extrusion, as this slicer writes)."""
    times = []
    position: list[str] = []
    for kind, part in parts:
        if kind == "layer":
            start = [f"G92 {' '.join(position)}"] if position else []
            times.append(summarize(["M83", *start, *part], settings).time_s)
        position = _end_position(part, position)
    return times


def _end_position(lines: list[str], before: list[str]) -> list[str]:
    """The X, Y and Z words of the last position ``lines`` move to (``before`` otherwise)."""
    last = {word[0]: word for word in before}
    for line in lines:
        if line.startswith(("G0 ", "G1 ", "G2 ", "G3 ")):
            for word in line.split(";", 1)[0].split()[1:]:
                if word[0] in "XYZ":
                    last[word[0]] = word
    return [last[axis] for axis in "XYZ" if axis in last]


def annotate_program(
    out: TextIO, read_body: Callable[[], Iterable[str]], plan: SlicePlan,
    settings: SliceSettings, labels: ObjectLabels | None,
    times: list[float] | None = None,
) -> None:
    """Write a streamed program (``read_body()`` gives its lines, twice) with labels and M73.

    ``times`` are the layers' seconds; without them a first reading times each
    layer (:func:`slicer.output.gcode.summarize`). The last reading writes every part,
    each layer labelled and given its ``M73``. One layer is held at a time.
    """
    if times is None:
        times = layer_times(_split(read_body()), settings)
    total = sum(times)
    before = 0.0
    index = 0
    for kind, part in _split(read_body()):
        if kind == "layer":
            layer = int(part[0][7:])
            if labels is not None:
                part = labels.label_layer(layer, part)
            part = [part[0], progress_line(before, total), *part[1:]]
            before += times[index]
            index += 1
        elif kind == "end":
            part = [progress_line(total, total), *part]
        out.write("\n".join(part) + "\n")


def annotate_file(
    out: TextIO, path: str | os.PathLike[str], plan: SlicePlan, settings: SliceSettings,
    times: list[float] | None = None,
) -> None:
    """After a header: the extras, then the program streamed to ``path``, annotated
    (``times``: each layer's seconds, when known)."""
    labels = object_labels(plan, settings)
    extras = header_extras(plan, settings, labels)
    if extras:
        out.write("\n".join(extras) + "\n")

    def read_body() -> Iterator[str]:
        with open(path, encoding="utf-8") as handle:
            for line in handle:
                yield line.rstrip("\n")

    annotate_program(out, read_body, plan, settings, labels, times)


def write_annotated(
    plan: SlicePlan, final: str | os.PathLike[str], path: str | os.PathLike[str],
    header: list[str], settings: SliceSettings, times: list[float] | None = None,
) -> None:
    """Write ``final``: ``header``'s lines, then :func:`annotate_file` of the program
    streamed to ``path``, flushed to the disk. A function of the plan first, so that a
    host can run it where the plan lives (:meth:`slicer.planprocess.PlanProcess.call`):
    the thumbnails and labels cut every layer's outline."""
    with open(final, "w", encoding="utf-8", newline="\n") as out:
        for line in header:
            out.write(line + "\n")
        annotate_file(out, path, plan, settings, times)
        out.flush()
        os.fsync(out.fileno())
