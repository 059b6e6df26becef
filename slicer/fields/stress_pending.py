"""Field files still being computed: a stress field naming one waits for it when sampled."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from slicer.fea.field import FieldFile

# field files still being computed (an analysis running while the first layers print):
# path -> a future that completes when the file is written
_PENDING: dict[str, Future[FieldFile]] = {}
_PENDING_LOCK = threading.Lock()
# field files a layer is waiting for right now: path -> layers waiting
_WAITING: dict[str, int] = {}
# computations held back until released (see `hold`): path -> what releases them
_HOLDS: dict[str, threading.Event] = {}


def hold(path: str | Path, release: threading.Event) -> None:
    """Say that the computation of ``path`` waits for ``release``: a layer that comes to
    wait for the file (:func:`waiting`) sets it, so no layer waits for a held one."""
    with _PENDING_LOCK:
        _HOLDS[str(path)] = release


def announce(path: str | Path, future: Future[FieldFile]) -> None:
    """Say that the field file ``path`` is being computed by ``future``: a stress field
    naming it is built at once and waits for it only when first sampled."""
    with _PENDING_LOCK:
        _PENDING[str(path)] = future
    future.add_done_callback(lambda _f: _forget(str(path), future))


def _forget(path: str, future: Future[FieldFile]) -> None:
    with _PENDING_LOCK:
        _HOLDS.pop(path, None)
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


@contextmanager
def waiting(path: str | os.PathLike[str]) -> Iterator[None]:
    """Mark, for as long as the block runs, that a layer waits for the field file
    ``path`` (see :func:`waited_for`)."""
    key = str(path)
    with _PENDING_LOCK:
        _WAITING[key] = _WAITING.get(key, 0) + 1
        held = _HOLDS.get(key)
    if held is not None:
        held.set()  # a layer needs the field: the computation may wait no longer
    try:
        yield
    finally:
        with _PENDING_LOCK:
            left = _WAITING.pop(key) - 1
            if left:
                _WAITING[key] = left


def waited_for(path: str | os.PathLike[str]) -> bool:
    """True while some layer is waiting for the field file ``path`` to be computed."""
    with _PENDING_LOCK:
        return str(path) in _WAITING
