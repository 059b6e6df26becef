"""The job being printed as its G-code file shows it: each layer's text, filament used, picture."""

from __future__ import annotations

import contextlib
import io
import logging
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hostd.jobs.jobfolder import split_name

log = logging.getLogger("hostd.publishing.jobinfo")

_LAYER = re.compile(rb"(?m)^;LAYER:(-?\d+)\r?\n")
_E_WORD = re.compile(rb"(?m)^G[01][^;\n]* E(-?[0-9.]+)")
_KEPT_LAYERS = 3  # layer texts kept for pictures: the last completed one and the ones after it


@dataclass
class _Current:
    """What is known of the job printing now."""

    id: str
    name: str
    layers: int
    part: Path
    density_g_mm: float  # grams per mm of filament
    offset: int = 0
    last_index: int | None = None
    completed: int = -1
    counted: int = -1  # the last layer whose filament is in ``filament_mm``
    filament_mm: float = 0.0


class JobTracker:
    """Reads the printing job's G-code file (``<area>/<id>/NAME.gcode.part``) as layers complete.

    A resumed job is followed from its resume layer on (its filament counts
    the layers printed since). ``on_event`` is a
    :meth:`hostd.publishing.status.StatusHub.listen` listener: at each
    ``layer`` event the file holds every line written so far (the runner
    flushes it before the event), so the new bytes are read then and split at
    ``;LAYER:`` lines; filament is the sum of the E words of completed layers
    (extrusion is relative). Memory is bounded: only the last few layers'
    texts are kept. ``settings_of(job_id)`` gives the job's flat settings (for
    the filament's grams per mm).
    """

    def __init__(self, area: Path, settings_of: Any = None) -> None:
        self.area = area
        self.settings_of = settings_of
        self.current: _Current | None = None
        self.last: _Current | None = None  # the job that ended last
        self._texts: dict[int, bytes] = {}
        self._lock = threading.Lock()

    def on_event(self, event: dict[str, Any]) -> None:
        """Follow one hub event (see the class docstring)."""
        kind = event.get("event")
        if kind == "started":
            self._start(event)
        elif self.current is None or str(event.get("id")) != self.current.id:
            return
        elif kind == "layer":
            self._read()
            self.current.completed = int(event.get("layer", -1))
            self._count()
        elif kind in ("done", "failed", "cancelled", "interrupted"):
            self.last = self.current
            self.current = None

    def _start(self, event: dict[str, Any]) -> None:
        job_id, name = str(event.get("id")), str(event.get("name"))
        stem, _suffix = split_name(name)
        density = 0.0
        if self.settings_of is not None:
            try:
                density = grams_per_mm(self.settings_of(job_id))
            except Exception:  # an unknown job or odd settings: no grams, still mm
                log.debug("no filament density for job %s", job_id, exc_info=True)
        part = self.area / job_id / f"{stem}.gcode.part"
        self.current = _Current(job_id, name, int(event.get("layers") or 0), part, density)
        first = event.get("resumed_from")
        if first:  # the layers printed before are not read again (bounded work at each event)
            self.current.completed = self.current.counted = int(first) - 1
            with contextlib.suppress(OSError):
                self.current.offset = part.stat().st_size
        with self._lock:
            self._texts.clear()

    def _read(self) -> None:
        """Take the bytes written since the last read and file them under their layers."""
        job = self.current
        assert job is not None
        try:
            with open(job.part, "rb") as handle:
                handle.seek(job.offset)
                data = handle.read()
        except OSError:
            return
        job.offset += len(data)
        parts = _LAYER.split(data)
        with self._lock:
            if job.last_index is not None:
                self._texts[job.last_index] = self._texts.get(job.last_index, b"") + parts[0]
            for number, body in zip(parts[1::2], parts[2::2], strict=True):
                index = int(number)
                self._texts[index] = body
                job.last_index = index

    def _count(self) -> None:
        """Add the filament of the layers completed since the last count; forget old texts."""
        job = self.current
        assert job is not None
        with self._lock:
            for index in sorted(self._texts):
                if job.counted < index <= job.completed:
                    job.filament_mm += filament_of(self._texts[index])
                    job.counted = index
            for index in [i for i in self._texts if i < job.completed]:
                del self._texts[index]

    def layer_text(self, index: int) -> str | None:
        """The G-code of layer ``index`` if it is still kept, else None."""
        with self._lock:
            text = self._texts.get(index)
        return None if text is None else text.decode("utf-8", "replace")

    def picture_layer(self, wanted: int) -> int | None:
        """The kept layer closest to ``wanted`` from below (the one a picture can show), or None."""
        with self._lock:
            kept = [i for i in self._texts if i <= wanted]
        return max(kept) if kept else None

    def info(self) -> dict[str, Any] | None:
        """The current (or last) job: id, name, layers, completed layer, filament in mm and g."""
        job = self.current or self.last
        if job is None:
            return None
        return {
            "id": job.id,
            "name": job.name,
            "layers": job.layers,
            "completed": job.completed,
            "printing": job is self.current,
            "filament_mm": round(job.filament_mm, 2),
            "filament_g": round(job.filament_mm * job.density_g_mm, 2),
        }


def grams_per_mm(settings: dict[str, Any]) -> float:
    """Grams per mm of filament for flat settings (defaults for the keys not given)."""
    from slicer.settings import SliceSettings

    parsed = SliceSettings.from_mapping(settings)
    return parsed.filament_area * parsed.filament_density / 1000.0


def filament_of(text: bytes) -> float:
    """Net filament (mm) of relative-extrusion G-code: the sum of its G0/G1 E words."""
    words = _E_WORD.findall(text)
    return float(np.asarray(words, dtype=np.float64).sum()) if words else 0.0


_COLOURS = {
    "WALL-OUTER": (220, 50, 47),
    "WALL-INNER": (245, 150, 40),
    "SKIN": (200, 170, 0),
    "FILL": (40, 160, 70),
    "SUPPORT": (60, 110, 220),
}
_MOVE = re.compile(r"^(?:;TYPE:(\S+)|G([01])\b([^;]*))", re.M)
_WORD = re.compile(r"([XYE])(-?[0-9.]+)")


def extrusions(text: str) -> tuple[np.ndarray, list[str]]:
    """The extruding moves of one layer's G-code (absolute X Y, relative E).

    Returns ``(segments, kinds)``: segments float64 (n, 4) as x0 y0 x1 y1 in mm
    and the ``;TYPE:`` of each (empty before the first type comment).
    """
    x = y = None
    kind = ""
    segments: list[tuple[float, float, float, float]] = []
    kinds: list[str] = []
    for match in _MOVE.finditer(text):
        if match.group(1):
            kind = match.group(1)
            continue
        words = dict(_WORD.findall(match.group(3)))
        nx = float(words["X"]) if "X" in words else x
        ny = float(words["Y"]) if "Y" in words else y
        extruding = float(words.get("E", 0.0)) > 0
        if extruding and x is not None and y is not None and nx is not None and ny is not None \
                and (nx != x or ny != y):
            segments.append((x, y, nx, ny))
            kinds.append(kind)
        x, y = nx, ny
    return np.asarray(segments, dtype=np.float64).reshape(-1, 4), kinds


def layer_png(text: str, title: str, size: int = 480,
              frame: tuple[float, float, float, float] | None = None) -> bytes:
    """A PNG of one layer's extruding moves, coloured by type, ``size`` px on its longer side.

    ``frame`` (xmin, ymin, xmax, ymax in mm) fixes the view; by default it is
    the layer's own extent with a 3 mm margin.
    """
    from PIL import Image, ImageDraw

    segments, kinds = extrusions(text)
    if frame is None:
        if len(segments):
            xs, ys = segments[:, [0, 2]], segments[:, [1, 3]]
            frame = (xs.min() - 3, ys.min() - 3, xs.max() + 3, ys.max() + 8)  # room for the title
        else:
            frame = (0.0, 0.0, 10.0, 10.0)
    xmin, ymin, xmax, ymax = frame
    scale = size / max(xmax - xmin, ymax - ymin, 1e-6)
    width, height = max(1, round((xmax - xmin) * scale)), max(1, round((ymax - ymin) * scale))
    image = Image.new("RGB", (width, height), (250, 250, 247))
    draw = ImageDraw.Draw(image)
    px = np.empty_like(segments)
    px[:, [0, 2]] = (segments[:, [0, 2]] - xmin) * scale
    px[:, [1, 3]] = (ymax - segments[:, [1, 3]]) * scale
    line = max(1, round(0.4 * scale * 0.8))
    for (x0, y0, x1, y1), kind in zip(px.tolist(), kinds, strict=True):
        draw.line((x0, y0, x1, y1), fill=_COLOURS.get(kind, (90, 90, 90)), width=line)
    draw.text((6, 3), title, fill=(0, 0, 0))
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()
