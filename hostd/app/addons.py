"""What the daemon feeds from its job events: job tracker, notifications, history, MQTT extras."""

from __future__ import annotations

from typing import Any

from hostd.config import Config
from hostd.jobs.jobstore import JobStore
from hostd.publishing.history import HISTORY_FILE, History, HistoryRecorder, PrintRecord
from hostd.publishing.jobinfo import JobTracker
from hostd.publishing.mqtt_extras import MqttExtras
from hostd.publishing.notify import Notifier
from hostd.publishing.status import StatusHub


class Addons:
    """The listeners of one daemon's hub, registered in the order they must see each event.

    The tracker first (it reads the layer the event completes), then the
    notifier, which takes the layer's text from it, then the history, then the
    extra MQTT topics (which publish the history's new totals).
    """

    LAST_JOBS = 5  # finished jobs in the status snapshot

    def __init__(self, config: Config, store: JobStore, hub: StatusHub) -> None:
        self.tracker = JobTracker(config.state.folder / "jobs", lambda job: _settings(store, job))
        self.notifier = Notifier(config.notify, hub, self.tracker)
        self.history = History(config.state.folder / HISTORY_FILE)
        self.hub = hub
        recorder = HistoryRecorder(self.history, store, self.tracker, self._recorded)
        self.mqtt_extras = MqttExtras(config.printer.id, self.tracker, self.history)
        for listener in (self.tracker, self.notifier, recorder, self.mqtt_extras):
            hub.listen(listener.on_event)
        self._recorded(None)

    def _recorded(self, _record: PrintRecord | None) -> None:
        """Put the last finished jobs into the status snapshot."""
        hub = self.hub
        hub.update(history=tuple(r.brief() for r in self.history.records(self.LAST_JOBS)))

    def close(self) -> None:
        """At stop: let queued notifications go out for a moment."""
        self.notifier.close()
        self.history.close()


def _settings(store: JobStore, job_id: str) -> dict[str, Any]:
    return store.get(job_id).settings
