"""Job store test doubles: one that records its checkpoints and commits, and can be slow."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from hostd.jobs.jobstore import JobStore


class CommitLog:
    """Every commit of a store and of the connections reopened from it: when it ran
    (monotonic start and end) and in which thread; and how many are under way now."""

    def __init__(self) -> None:
        self.spans: list[tuple[float, float, str]] = []
        self._under_way = 0
        self._lock = threading.Lock()

    @property
    def under_way(self) -> int:
        """Commits in progress at this moment."""
        return self._under_way

    def begin(self) -> float:
        with self._lock:
            self._under_way += 1
        return time.monotonic()

    def end(self, began: float) -> None:
        with self._lock:
            self._under_way -= 1
            self.spans.append((began, time.monotonic(), threading.current_thread().name))


class RecordingStore(JobStore):
    """A job store that records every checkpoint committed, and the thread that committed it;
    each commit takes ``commit_delay_s`` more (a slow card) and is logged in :attr:`commits`.

    Connections made by :meth:`reopen` share the records of the store they came from.
    """

    def __init__(self, path: Path, commit_delay_s: float = 0.0,
                 shared: RecordingStore | None = None) -> None:
        self.commit_delay_s = commit_delay_s
        self.checkpoints: list[tuple[int, int, int, int]] = shared.checkpoints if shared else []
        self.threads: list[str] = shared.threads if shared else []
        self.commits: CommitLog = shared.commits if shared else CommitLog()
        super().__init__(path)

    def _commit(self) -> None:
        began = self.commits.begin()
        try:
            if self.commit_delay_s:
                time.sleep(self.commit_delay_s)  # a slow card: each commit's fsync takes this long
            super()._commit()
        finally:
            self.commits.end(began)

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
