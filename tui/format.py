"""Text the dashboard shows: layer numbers, lengths, events, all fitting one line."""

from __future__ import annotations

import re
import time
from typing import Any

from rich.cells import cell_len


def layer_text(index: int, count: int) -> str:
    """A 0-based layer index as people read it: ``layer 13 of 25``."""
    return f"layer {index + 1} of {count}"


def metres(mm: float | None) -> str:
    """Filament length: ``1.25 m``, ``--`` when unknown."""
    return "--" if mm is None else f"{mm / 1000:.2f} m"


def clock(ts: float) -> str:
    """Local ``HH:MM:SS`` of a Unix time."""
    return time.strftime("%H:%M:%S", time.localtime(ts))


def describe_event(event: dict[str, Any]) -> tuple[str, str]:
    """(colour, text) of a job event, without its time."""
    kind = str(event.get("event", "?"))
    name = event.get("name", "")
    layers = event.get("layers")
    layer = event.get("layer")
    if kind == "layer" and isinstance(layer, int) and isinstance(layers, int):
        return "cyan", f"{layer_text(layer, layers)} done"
    if kind == "started":
        resumed = event.get("resumed_from")
        how = f"resumed at layer {resumed + 1}:" if isinstance(resumed, int) else "started"
        return "green", f"{how} {name} ({layers} layers)"
    if kind in ("paused", "resumed", "interrupted") and isinstance(layer, int):
        return "yellow", f"{kind} after layer {layer + 1}" if layer >= 0 else kind
    if kind == "object_cancelled":
        return "magenta", (f"body {event.get('object')} cancelled from layer "
                           f"{int(event.get('from_layer', 0)) + 1}")
    if kind == "object_restored":
        return "magenta", f"body {event.get('object')} restored"
    if kind in ("done", "failed", "cancelled", "queued"):
        colour = {"done": "green", "queued": "cyan"}.get(kind, "red")
        reason = event.get("reason") or event.get("error") or ""
        return colour, f"{kind}: {name} {reason}".rstrip()
    if kind == "error":
        reason = event.get("message") or event.get("reason") or ""
        if event.get("cmd"):  # a command the printer refused (MQTT answers on its event topic)
            return "red", f"refused {event['cmd']}: {reason}".rstrip()
        return "red", f"error: {reason}".rstrip()
    details = " ".join(f"{k}={v}" for k, v in event.items() if k not in ("event", "ts", "id"))
    return "white", f"{kind} {details}".rstrip()


def fit_words(text: str, width: int) -> str:
    """``text`` on one line of ``width`` cells: whole when it fits, else cut after its
    last whole word that leaves room for ``…`` (a single word too long is cut where it
    must be)."""
    if cell_len(text) <= width:
        return text
    if width <= 1:
        return "…"[:max(width, 0)]
    room = width - 1
    cut = 0
    for word in re.finditer(r"\S+", text):
        if cell_len(text[:word.end()]) > room:
            break
        cut = word.end()
    if cut == 0:  # not even the first word fits: cut inside it
        cut = len(text)
        while cut and cell_len(text[:cut]) > room:
            cut -= 1
    return text[:cut].rstrip() + "…"
