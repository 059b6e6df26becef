"""ASCII STL reading: every ``vertex`` line, in chunks, with a specific refusal for what is wrong.

Read as other slicers read it: the ``solid``/``facet``/``outer loop`` words are
checked only as far as they tell facets apart; a missing ``endsolid`` (or several
solids in one file) changes nothing.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator

import numpy as np

from slicer.errors import ModelError

# bytes parsed per step, cut at a line end (bounds memory on big files)
_CHUNK = 8 << 20
_VERTEX = re.compile(rb"^[ \t]*vertex\b([^\n]*)", re.M | re.I)
_FACET = re.compile(rb"^[ \t]*facet\b", re.M | re.I)
_NUMBERS = re.compile(rb"^[ \t]+(\S+)[ \t]+(\S+)[ \t]+(\S+)[ \t\r]*$")


def _chunks(path: str | os.PathLike[str]) -> Iterator[tuple[bytes, int]]:
    """(text, line number of its first line) for the file, in pieces cut at line ends."""
    line = 1
    rest = b""
    with open(path, "rb") as fh:
        while True:
            data = fh.read(_CHUNK)
            if not data:
                break
            data = rest + data
            cut = data.rfind(b"\n") + 1
            if cut == 0:
                rest = data
                continue
            yield data[:cut], line
            line += data.count(b"\n", 0, cut)
            rest = data[cut:]
    if rest:
        yield rest + b"\n", line


def read_ascii_corners(path: str | os.PathLike[str]) -> np.ndarray:
    """Corners (3n, 3) float32 of an ASCII STL, three per facet, in file order.

    Raises ModelError naming the line for a vertex without three numbers, a
    facet without exactly three vertices (for instance a file cut short inside
    one), and a file with no facet at all.
    """
    parts: list[np.ndarray] = []
    facets = 0
    for text, first_line in _chunks(path):
        found = _VERTEX.findall(text)
        facets += len(_FACET.findall(text))
        if not found:
            continue
        matches = [_NUMBERS.match(rest) for rest in found]
        rows = [m for m in matches if m is not None]
        if len(rows) < len(matches):
            k = next(i for i, m in enumerate(matches) if m is None)
            raise ModelError(f"ASCII STL: the vertex on line {_line_of(text, k, first_line)} "
                             "does not have three coordinates")
        try:
            corners = np.array([m.groups() for m in rows], dtype=np.bytes_).astype(np.float64)
        except ValueError:
            k = next(i for i, m in enumerate(rows) if not _numbers_ok(m.groups()))
            raise ModelError(f"ASCII STL: the vertex on line {_line_of(text, k, first_line)} "
                             "has a coordinate that is not a number") from None
        parts.append(corners.astype(np.float32))
    corners = np.concatenate(parts) if parts else np.empty((0, 3), dtype=np.float32)
    if facets == 0 and len(corners) == 0:
        raise ModelError("ASCII STL: no facets (the file has a 'solid' line but no triangles)")
    if len(corners) != 3 * facets:
        raise ModelError(_facet_problem(path, facets, len(corners)))
    return corners


def _numbers_ok(words: tuple[bytes, ...]) -> bool:
    try:
        [float(w) for w in words]
    except ValueError:
        return False
    return True


def _line_of(text: bytes, k: int, first_line: int) -> int:
    """Line number of the ``k``-th vertex line of ``text``."""
    match = next(m for i, m in enumerate(_VERTEX.finditer(text)) if i == k)
    return first_line + text.count(b"\n", 0, match.start())


def _facet_problem(path: str | os.PathLike[str], facets: int, vertices: int) -> str:
    """Which facet does not have three vertices, as a sentence (the slow path of a refusal)."""
    facet_line = 0
    count = 3
    number = 0
    for text, first_line in _chunks(path):
        for m in re.finditer(rb"^[ \t]*(facet|vertex)\b", text, re.M | re.I):
            if m.group(1).lower() == b"facet":
                if count != 3:
                    break
                number += 1
                count = 0
                facet_line = first_line + text.count(b"\n", 0, m.start())
            else:
                count += 1
        else:
            continue
        break
    if number == 0:
        return "ASCII STL: vertex lines before the first 'facet' line"
    if count == 3:
        return (f"ASCII STL: {vertices} vertices for {facets} facets "
                "(a vertex outside any facet)")
    ends = " (the file ends inside it: cut short?)" if number == facets else ""
    return f"ASCII STL: facet {number} (line {facet_line}) has {count} vertices, not 3{ends}"
