"""Notifications through Apprise: job events become messages, sent off the event loop, bounded."""

from __future__ import annotations

import logging
import queue
import threading
from dataclasses import dataclass
from typing import Any, Protocol

from hostd.api import duration
from hostd.publishing.jobinfo import JobTracker, layer_png

log = logging.getLogger("hostd.publishing.notify")

QUEUE_SIZE = 16  # messages waiting to be sent; more are dropped (and logged)


class NotifySettings(Protocol):
    """The ``[notify]`` section (``hostd.config.NotifyConfig``)."""

    urls: tuple[str, ...]
    events: tuple[str, ...]
    timeout_s: float
    picture: bool


class SnapshotSource(Protocol):
    """Anything with the current status snapshot (``hostd.publishing.status.StatusHub``)."""

    @property
    def current(self) -> Any: ...


@dataclass(frozen=True)
class Message:
    """One notification: title, body, Apprise type, and the layer to picture (G-code text)."""

    kind: str
    title: str
    body: str
    notify_type: str = "info"
    layer_text: str | None = None
    layer: int | None = None


class Notifier:
    """Turns hub events into notifications sent by one worker thread.

    :meth:`on_event` is a :meth:`hostd.publishing.status.StatusHub.listen` listener: it
    composes the message at once (so it names the job as it is at that
    moment) and puts it on a bounded queue without waiting; a full queue drops
    the message. The worker renders the layer's PNG and sends through Apprise
    with ``timeout_s`` as connect and read timeout for each URL, so an
    endpoint that fails or hangs delays only the notifications after it.
    """

    def __init__(self, settings: NotifySettings, hub: SnapshotSource | None = None,
                 tracker: JobTracker | None = None, queue_size: int = QUEUE_SIZE) -> None:
        self.settings = settings
        self.hub = hub
        self.tracker = tracker
        self._queue: queue.Queue[Message | None] = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None
        self._closed = False
        self.sent = 0
        self.failed = 0
        self.dropped = 0

    # -- on the event loop ----------------------------------------------------

    def on_event(self, event: dict[str, Any]) -> None:
        """Queue the notification for ``event`` if its kind is wanted (never blocks)."""
        if self._closed or not self.settings.urls:
            return
        message = self.compose(event)
        if message is None or message.kind not in self.settings.events:
            return
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name="hostd-notify", daemon=True)
            self._thread.start()
        try:
            self._queue.put_nowait(message)
        except queue.Full:
            self.dropped += 1
            log.warning("notification dropped (%d waiting): %s", self._queue.qsize(), message.title)

    def compose(self, event: dict[str, Any]) -> Message | None:
        """The message for one event, or None for events that are not notified."""
        kind = event.get("event")
        name = event.get("name") or "a job"
        job_id = event.get("id")
        label = f"{name} (job {job_id})" if job_id is not None else str(name)
        info = self.tracker.info() if self.tracker is not None else None
        if info is not None and str(info["id"]) != str(job_id):
            info = None
        completed = info["completed"] if info else -1
        if kind == "layer":
            if event.get("layer") != 0:
                return None
            layers = event.get("layers") or (info["layers"] if info else 0)
            return self._with_layer(Message(
                "first_layer", f"{name}: first layer done",
                f"{label}: the first of {layers} layers is printed; have a look at it.",
            ), 0)
        if kind == "done":
            body = f"{label} is done."
            if info:
                body += f" {info['layers']} layers, filament {info['filament_mm'] / 1000:.2f} m"
                body += f" ({info['filament_g']:.1f} g)." if info["filament_g"] else "."
            elapsed = self._elapsed(job_id)
            if elapsed is not None:
                body += f" Time {duration(elapsed)}."
            return self._with_layer(Message("done", f"{name} printed", body, "success"),
                                    completed)
        if kind in ("failed", "cancelled"):
            reason = event.get("reason") or "no reason given"
            verb = "failed" if kind == "failed" else "was cancelled"
            where = f" at layer {completed + 2}" if info and completed >= -1 and info["printing"] \
                else ""
            return self._with_layer(Message(
                kind, f"{name} {verb}", f"{label} {verb}{where}: {reason}",
                "failure" if kind == "failed" else "warning",
            ), completed + 1 if info else None)
        if kind == "paused":
            layer = int(event.get("layer", completed))
            return self._with_layer(Message(
                "paused", f"{name} paused", f"{label} is paused at layer {layer + 2}"
                f" (layer {layer + 1} is the last one finished). Resume or cancel it.",
                "warning",
            ), layer + 1 if info else None)
        if kind == "interrupted":
            return Message("interrupted", f"{name} interrupted",
                           f"{label} stopped after layer {int(event.get('layer', -1)) + 1};"
                           f" `hostd resume {job_id}` continues it.", "warning")
        if kind == "error" and "cmd" not in event:  # refused commands are answers, not alarms
            text = event.get("message") or event.get("reason") or "unknown error"
            source = "printer" if event.get("source") == "printer" else f"job {job_id}"
            return self._with_layer(Message("error", f"hostd: {source} error", f"{source}: {text}",
                                            "failure"), completed + 1 if info else None)
        return None

    def _with_layer(self, message: Message, wanted: int | None) -> Message:
        """Attach the G-code text of ``wanted`` (or the nearest kept layer below it)."""
        if not self.settings.picture or self.tracker is None or wanted is None:
            return message
        layer = self.tracker.picture_layer(wanted)
        if layer is None:
            return message
        text = self.tracker.layer_text(layer)
        return Message(message.kind, message.title, message.body, message.notify_type, text, layer)

    def _elapsed(self, job_id: Any) -> float | None:
        current = getattr(self.hub, "current", None)
        job = getattr(current, "job", None)
        if job is None or str(job.id) != str(job_id):
            return None
        return float(job.elapsed_s)

    # -- the worker thread ----------------------------------------------------

    def _work(self) -> None:
        while True:
            message = self._queue.get()
            if message is None:
                return
            try:
                ok = self.send(message)
            except Exception:  # Apprise or a picture failing must not end the worker
                log.exception("notification %r failed", message.title)
                ok = False
            if ok:
                self.sent += 1
            else:
                self.failed += 1
                log.warning("notification %r was not delivered to every URL", message.title)

    def send(self, message: Message) -> bool:
        """Send one message to every URL (blocking); True when all of them took it."""
        import apprise
        from apprise.attachment.memory import AttachMemory

        sender = apprise.Apprise()
        for url in self.settings.urls:
            plugin = apprise.Apprise.instantiate(url)
            if plugin is None:
                log.error("notify.urls: Apprise does not understand %r", _redact(url))
                continue
            plugin.socket_connect_timeout = self.settings.timeout_s
            plugin.socket_read_timeout = self.settings.timeout_s
            sender.add(plugin)
        if not len(sender):
            return False
        attach = None
        if message.layer_text is not None and message.layer is not None:
            png = layer_png(message.layer_text, f"{message.title}: layer {message.layer + 1}")
            attach = AttachMemory(content=png, name=f"layer-{message.layer + 1}.png",
                                  mimetype="image/png")
        return bool(sender.notify(body=message.body, title=message.title,
                                  notify_type=message.notify_type, attach=attach))

    def close(self, wait_s: float = 2.0) -> None:
        """Stop taking events; give the messages queued up to ``wait_s`` to go out."""
        self._closed = True
        if self._thread is None:
            return
        try:
            self._queue.put(None, timeout=wait_s)
        except queue.Full:
            return
        self._thread.join(wait_s)


def _redact(url: str) -> str:
    """A URL without what may be a secret (everything after the scheme's host part)."""
    scheme, _sep, rest = url.partition("://")
    return f"{scheme}://{rest.split('/')[0].rsplit('@', 1)[-1]}/..."
