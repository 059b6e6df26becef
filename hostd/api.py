"""The daemon's public API: the status snapshot schema, the control socket's and MQTT's protocol.

This is the one module of `hostd` that clients (the dashboard in `tui/`, scripts)
import. It depends on the standard library only (and on `hostd.textforms`, the
durations and progress bars it re-exports, which does too).

Control socket protocol: a Unix stream socket, one JSON object per line each way.
Requests carry ``{"cmd": NAME, ...args}`` and an optional ``"id"``; each gets one
reply ``{"reply": NAME, "ok": true|false, "id": ..., "error": text|null, ...}``.
``{"cmd": "subscribe"}`` turns the connection into a stream of
``{"status": SNAPSHOT}`` and ``{"event": EVENT}`` lines.

``{"cmd": "emergency_stop"}`` (also over MQTT): ``M112`` at once, out of band when the
firmware has an emergency parser. The printer halts; the job printing, if any, fails
("emergency stop (M112)") and is not resumable; the daemon then opens the link again
(the board resets). The reply's ``job`` is the failed job's id, or null when idle; it
is refused ("no printer is connected") while the printer is offline.

Requests for the dashboard (on the control socket as above; ``layer`` and
``estimate`` change nothing and are MQTT requests too, see below):

- ``{"cmd": "layer", "layer": N, "tolerance": MM, "field": [COLS, ROWS]}``: one layer
  of the job printing (``layer`` defaults to the one printing; ``tolerance``, default
  0.2 mm, simplifies the polylines; ``field`` is optional). The reply adds ``layer``,
  ``layers``, ``z`` (mm), ``bounds`` ([xmin, ymin, xmax, ymax] mm of the whole model,
  the same frame for every layer), ``paths`` (in print order, each ``{"kind": TYPE,
  "points": [[x, y], ...], "end": K}``: TYPE is the G-code's ``;TYPE:`` name such as
  WALL-OUTER, WALL-INNER, SKIN, FILL, SUPPORT; the path is printed once K of the
  layer's ``commands`` are acknowledged), ``commands``, ``acked_before`` (the job's
  ``lines_acked`` when the layer started streaming, or null when unknown), ``next_unsliced``
  (the first layer not sliced yet), ``body_count``, ``bodies`` (with more than one body:
  ``{"index", "cancelled", "rings": [[[x, y], ...], ...]}`` outlines on this layer),
  ``cancelled`` (``[{"object", "from_layer"}]``) and ``field`` (null, or ``{"name",
  "columns", "rows", "low", "high", "values"}``: rows top first over ``bounds``, each
  value 0..255 between ``low`` and ``high``, -1 outside the layer).
- ``{"cmd": "estimate", "settings": {KEY: VALUE}}``: the job's ``filament_used_mm``
  and ``filament_total_mm`` estimated from a few sliced layers, ``eta_s``, ``settings``
  (the retunable values now: infill.density, infill.field, nozzle_temp, bed_temp),
  ``fields`` (the infill field names), and with
  ``settings`` (optional, checked as ``set`` checks them, not applied) ``retuned``:
  ``{"filament_total_mm", "eta_s", "time_ratio"}`` if the retune were made now.
- ``{"cmd": "restore_object", "object": N}``: undo ``cancel_object`` while no layer
  without that body has been sliced yet (a command, like ``cancel_object``).

Over MQTT (3.1.1, topics ``hostd/<printer>/...``; the daemon's side is
``hostd.publishing.mqtt`` and ``hostd.publishing.mqtt_requests``):

- ``status`` (retained): the snapshot's JSON, as :meth:`Snapshot.to_json`; its job's
  ``filament_used_mm`` and ``filament_total_mm`` are the daemon's estimates.
- ``cmd``: the commands pause, resume, cancel, resume_job, cancel_object,
  restore_object, set and emergency_stop, as ``{"cmd": NAME, "id": ..., ...args}``;
  carried out only with ``mqtt.allow_commands`` and broker credentials on the
  printer's side. They have no reply: a refusal is an ``error`` event
  ``{"event": "error", "cmd", "reason", "id"}`` on ``event``.
- ``req``: the read-only requests ``layer`` and ``estimate`` as ``{"req": NAME, "id":
  ..., "reply_to": TOPIC, ...args}`` (the arguments above); allowed without
  ``allow_commands``. The reply, the same object as on the control socket, is
  published on ``reply_to`` (QoS 1, not retained), which must be
  ``hostd/<printer>/reply/<client>`` with ``<client>`` 1 to 64 letters, digits,
  ``-`` or ``_``; a request naming any other topic is not answered and is refused
  on ``event``. Requests are 16 KiB at most, replies 900 KiB (a larger one is
  refused); a client with 4 requests waiting, or a printer with 16, answers
  ``busy``.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import AsyncIterator
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

from hostd.textforms import bar as bar  # the text forms, re-exported for clients
from hostd.textforms import duration as duration

if TYPE_CHECKING:
    # imported when a control client connects (ControlClient.__aenter__): commands that
    # only read the schema do not pay for asyncio's import (with ssl, socket,
    # subprocess, inspect, logging)
    import asyncio

STATES = ("idle", "heating", "printing", "paused", "error", "offline")
COMMANDS = (
    "status",
    "subscribe",
    "pause",
    "resume",
    "cancel",
    "resume_job",
    "cancel_object",
    "set",
    "queue_move",
    "queue_remove",
    "restore_object",
    "layer",
    "estimate",
    "emergency_stop",
)
EVENTS = (
    "queued",
    "started",
    "layer",
    "paused",
    "resumed",
    "done",
    "failed",
    "cancelled",
    "interrupted",
    "object_cancelled",
    "object_restored",
    "retuned",
    "error",
    "repaired",
)


@dataclass(frozen=True)
class Temperature:
    """One heater: measured and target temperature, degrees C."""

    actual: float = 0.0
    target: float = 0.0


@dataclass(frozen=True)
class Temps:
    hotend: Temperature = field(default_factory=Temperature)
    bed: Temperature = field(default_factory=Temperature)


@dataclass(frozen=True)
class PrinterInfo:
    id: str = "sim"
    port: str = "sim"
    connected: bool = False


def layer_in_progress(completed: int, layers: int) -> int:
    """The 0-based layer being printed once layer ``completed`` (-1: none yet) is wholly
    acknowledged: the next one, at most the last (its end G-code still counts as it).

    ``JobStatus.layer`` of the daemon and ``hostd print``'s line both say this layer,
    read as ``layer N of M`` with N counted from 1.
    """
    return max(0, min(completed + 1, layers - 1))


@dataclass(frozen=True)
class JobStatus:
    """The job being printed. ``progress`` is 0..1; times in seconds; filament in mm."""

    id: str
    name: str
    layer: int = 0
    layers: int = 0
    progress: float = 0.0
    lines_acked: int = 0
    elapsed_s: float = 0.0
    eta_s: float | None = None
    layers_ready_ahead: int = 0
    # what the next layer waits for, when printing stops for it: "analysis" (the
    # stress analysis still running); None when nothing is waited for
    waiting_for: str | None = None
    # filament (mm) of the layers printed and of the whole job, estimated: the slicer's
    # figure of each layer sliced, a calibrated guess from the model's geometry for the
    # others (a retune or a cancelled body moves it at once); None for a G-code job and
    # before the first layer is sliced
    filament_used_mm: float | None = None
    filament_total_mm: float | None = None


_JOB_KEYS = frozenset(JobStatus.__dataclass_fields__)


@dataclass(frozen=True)
class InterruptedJob:
    id: str
    name: str
    layer: int


@dataclass(frozen=True)
class Snapshot:
    """The status snapshot of design.md: the same on MQTT, the socket and `hostd status`."""

    state: str = "idle"
    printer: PrinterInfo = field(default_factory=PrinterInfo)
    temps: Temps = field(default_factory=Temps)
    job: JobStatus | None = None
    queue: tuple[str, ...] = ()
    interrupted: tuple[InterruptedJob, ...] = ()
    error: str | None = None
    ts: float = field(default_factory=time.time)
    # the last finished jobs, newest first: {id, name, outcome, ended, print_s, filament_g}
    history: tuple[dict[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The snapshot as plain JSON-ready data (lists, dicts, numbers, strings)."""
        data = asdict(self)
        data["queue"] = list(self.queue)
        data["interrupted"] = [asdict(item) for item in self.interrupted]
        data["history"] = [dict(item) for item in self.history]
        return data

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Snapshot:
        """Rebuild a snapshot from :meth:`to_dict` output (unknown keys are ignored)."""
        temps = data.get("temps") or {}
        job = data.get("job")
        return cls(
            state=str(data.get("state", "offline")),
            printer=PrinterInfo(**(data.get("printer") or {})),
            temps=Temps(
                hotend=Temperature(**(temps.get("hotend") or {})),
                bed=Temperature(**(temps.get("bed") or {})),
            ),
            job=JobStatus(**{k: v for k, v in job.items() if k in _JOB_KEYS}) if job else None,
            queue=tuple(data.get("queue") or ()),
            interrupted=tuple(InterruptedJob(**item) for item in data.get("interrupted") or ()),
            error=data.get("error"),
            ts=float(data.get("ts", 0.0)),
            history=tuple(dict(item) for item in data.get("history") or ()),
        )


def accepted(cmd: str, request_id: Any, extra: dict[str, Any]) -> dict[str, Any]:
    """The reply to a request carried out: its fields and the envelope (socket and MQTT)."""
    return {**extra, "reply": cmd, "ok": True, "id": request_id, "error": None}


def refused(cmd: str | None, request_id: Any, reason: str) -> dict[str, Any]:
    """The reply to a request refused, with the reason (socket and MQTT)."""
    return {"reply": cmd, "ok": False, "id": request_id, "error": reason}


class ControlError(RuntimeError):
    """The daemon refused a command or could not be reached."""


MAX_REPLY_BYTES = 64 << 20  # a reply line (a layer's toolpaths) can be this long


class ControlClient:
    """Async client of the control socket: one request at a time, or a subscription."""

    def __init__(self, path: str) -> None:
        self.path = path
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def __aenter__(self) -> ControlClient:
        import asyncio

        try:
            self._reader, self._writer = await asyncio.open_unix_connection(
                self.path, limit=MAX_REPLY_BYTES
            )
        except OSError as exc:
            raise ControlError(f"cannot reach the daemon at {self.path}: {exc}") from exc
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(OSError):
                await self._writer.wait_closed()

    async def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one command and return its reply; raise ControlError when refused."""
        assert self._reader is not None
        assert self._writer is not None
        self._writer.write((json.dumps({"cmd": cmd, **args}) + "\n").encode())
        await self._writer.drain()
        while True:
            line = await self._reader.readline()
            if not line:
                raise ControlError("the daemon closed the connection")
            reply = json.loads(line)
            if "reply" in reply:
                break
        if not reply.get("ok", False):
            raise ControlError(reply.get("error") or f"{cmd} refused")
        return reply

    async def status(self) -> Snapshot:
        reply = await self.request("status")
        return Snapshot.from_dict(reply["status"])

    async def subscribe(self) -> AsyncIterator[dict[str, Any]]:
        """Yield ``{"status": Snapshot}`` and ``{"event": dict}`` items as they arrive."""
        await self.request("subscribe")
        assert self._reader is not None
        while True:
            line = await self._reader.readline()
            if not line:
                return
            item = json.loads(line)
            if "status" in item:
                yield {"status": Snapshot.from_dict(item["status"])}
            elif "event" in item:
                yield {"event": item["event"]}
