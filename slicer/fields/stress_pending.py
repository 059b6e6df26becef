"""Field files still being computed: a stress field naming one waits for it when sampled."""

from __future__ import annotations

import threading
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from slicer.fea.field import FieldFile

# field files still being computed (an analysis running while the first layers print):
# path -> a future that completes when the file is written
_PENDING: dict[str, Future[FieldFile]] = {}
_PENDING_LOCK = threading.Lock()


def announce(path: str | Path, future: Future[FieldFile]) -> None:
    """Say that the field file ``path`` is being computed by ``future``: a stress field
    naming it is built at once and waits for it only when first sampled."""
    with _PENDING_LOCK:
        _PENDING[str(path)] = future
    future.add_done_callback(lambda _f: _forget(str(path), future))


def _forget(path: str, future: Future[FieldFile]) -> None:
    with _PENDING_LOCK:
        if _PENDING.get(path) is future and not future.exception():
            del _PENDING[path]


def pending(path: str | Path) -> Future[FieldFile] | None:
    """The computation of ``path`` if one was announced and the file is not there yet
    (a failed computation stays, so every field naming it reports its error)."""
    with _PENDING_LOCK:
        future = _PENDING.get(str(path))
    if future is None or (future.done() and Path(path).is_file()):
        return None
    return future
