"""Retained MQTT topics besides the status: the job's figures, the layer's picture, the history."""

from __future__ import annotations

import asyncio
import json
from typing import Any, Protocol

import aiomqtt

from hostd.publishing.jobinfo import JobTracker, layer_png
from hostd.publishing.mqtt_calls import publish

IMAGE_SIZE = 480  # pixels on the picture's longer side


class HistorySummary(Protocol):
    """What gives the history's totals (``hostd.publishing.history.History``)."""

    def summary(self, last: int = 5) -> dict[str, Any]: ...


class MqttExtras:
    """Publishes ``hostd/<id>/job``, ``hostd/<id>/layer_image`` and ``hostd/<id>/history``.

    All three are retained. :meth:`on_event` (a hub listener) marks them
    stale at each job event; :meth:`publish` (one task per MQTT session)
    sends what changed: the job's figures (filament used so far, mm and g),
    a PNG of the layer being printed (rendered in a thread, once per layer)
    and the history's totals.
    """

    def __init__(self, printer_id: str, tracker: JobTracker,
                 history: HistorySummary | None = None) -> None:
        base = f"hostd/{printer_id}"
        self.job_topic = f"{base}/job"
        self.image_topic = f"{base}/layer_image"
        self.history_topic = f"{base}/history"
        self.tracker = tracker
        self.history = history
        self._changed: asyncio.Event | None = None

    def on_event(self, event: dict[str, Any]) -> None:
        """Mark the topics stale (called on the event loop's thread)."""
        if event.get("event") in ("started", "layer", "done", "failed", "cancelled",
                                  "interrupted") and self._changed is not None:
            self._changed.set()

    async def publish(self, client: aiomqtt.Client) -> None:
        """Publish now and after each job event until the session ends."""
        self._changed = changed = asyncio.Event()
        changed.set()
        shown: tuple[str, int] | None = None
        while True:
            await changed.wait()
            changed.clear()
            info = self.tracker.info()
            if info is not None:
                await publish(client, self.job_topic, json.dumps(info), qos=1, retain=True)
                layer = self.tracker.picture_layer(info["completed"] + 1)
                text = self.tracker.layer_text(layer) if layer is not None else None
                if text is not None and (info["id"], layer) != shown:
                    title = f"{info['name']}  layer {layer + 1} of {info['layers']}"
                    png = await asyncio.to_thread(layer_png, text, title, IMAGE_SIZE)
                    await publish(client, self.image_topic, png, qos=1, retain=True)
                    shown = (info["id"], layer)
            if self.history is not None:
                summary = self.history.summary()
                await publish(client, self.history_topic, json.dumps(summary), qos=1, retain=True)
