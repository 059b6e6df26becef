"""What the daemon feeds from its job events besides MQTT: the job tracker and notifications."""

from __future__ import annotations

from typing import Any

from hostd.config import Config
from hostd.jobinfo import JobTracker
from hostd.jobstore import JobStore
from hostd.notify import Notifier
from hostd.status import StatusHub


class Addons:
    """The listeners of one daemon's hub, registered in the order they must see each event.

    The tracker first (it reads the layer the event completes), then the
    notifier, which takes the layer's text from it.
    """

    def __init__(self, config: Config, store: JobStore, hub: StatusHub) -> None:
        self.tracker = JobTracker(config.state.folder / "jobs", lambda job: _settings(store, job))
        self.notifier = Notifier(config.notify, hub, self.tracker)
        hub.listen(self.tracker.on_event)
        hub.listen(self.notifier.on_event)

    def close(self) -> None:
        """At stop: let queued notifications go out for a moment."""
        self.notifier.close()


def _settings(store: JobStore, job_id: str) -> dict[str, Any]:
    return store.get(job_id).settings
