"""Job store test doubles: one that records its checkpoints, one whose commits are slow."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from hostd.jobstore import JobStore


class RecordingStore(JobStore):
    """A job store that records every checkpoint committed, and the thread that committed it.

    Connections made by :meth:`reopen` share the record of the store they came from.
    """

    def __init__(self, path: Path, commit_delay_s: float = 0.0,
                 shared: RecordingStore | None = None) -> None:
        self.commit_delay_s = commit_delay_s
        self.checkpoints: list[tuple[int, int, int, int]] = shared.checkpoints if shared else []
        self.threads: list[str] = shared.threads if shared else []
        super().__init__(path)

    def _commit(self) -> None:
        if self.commit_delay_s:
            time.sleep(self.commit_delay_s)  # a slow card: each commit's fsync takes this long
        super()._commit()

    def checkpoint(self, job_id: str, layer: int, lines_acked: int, gcode_bytes: int,
                   layer_lines: int = 0) -> None:
        super().checkpoint(job_id, layer, lines_acked, gcode_bytes, layer_lines)
        self.checkpoints.append((layer, lines_acked, gcode_bytes, layer_lines))
        self.threads.append(threading.current_thread().name)

    def reopen(self, durable: bool = True) -> RecordingStore:
        store = RecordingStore(self.path, self.commit_delay_s, shared=self)
        if not durable:
            store.relax()
        return store
