"""A model's load case checked when its job is taken; begun while the files settle."""

from __future__ import annotations

import asyncio
import importlib
import logging
import os
import threading
from pathlib import Path

from slicer.errors import ModelError
from slicer.settings import SliceSettings

log = logging.getLogger("hostd.jobs.loadcheck")

# (st_dev, st_ino, st_size, st_mtime_ns) of a path itself (a link is not followed)
Identity = tuple[int, int, int, int]

_ANALYSIS_MODULES = threading.Lock()  # held while (or once) they are being loaded


def load_analysis_modules() -> None:
    """Load the analysis' modules on a worker thread, once: from the moment a load case
    is seen in the job folder (before it and its model settle), so the stress job
    does not wait for the imports (seconds on a small board); a daemon that never
    sees a load case never loads them."""

    def load() -> None:
        for name in ("slicer.fea.field", "slicer.fea.tailor", "slicer.fields.stress",
                     "slicer.fields.stress_data"):
            importlib.import_module(name)

    if _ANALYSIS_MODULES.acquire(blocking=False):  # never released: once per process
        threading.Thread(target=load, name="fea-import", daemon=True).start()


def refusal(model: Path, load: Path, settings: dict[str, object], cache: Path) -> str | None:
    """Why a job whose load case (``NAME.load.toml``) cannot be analysed is refused (the
    case's own reason), or None. A model that cannot be read is left to the slicing,
    which fails the job with the model's reason. A case already analysed (its result
    in ``cache``) is known good: only its file is read again."""
    from slicer.fea.field import check_case, field_path  # loaded only when needed
    from slicer.fea.loadcase import LoadCaseError
    from slicer.fea.tailor import optimal_volume

    if load.is_symlink() or not load.is_file():
        return f"{load.name} must be a plain file"
    chosen = SliceSettings.from_mapping(settings)
    try:
        known = field_path(model, load, cache, chosen.fea_mesh_size,
                           chosen.fea_youngs_modulus_mpa, chosen.fea_poisson_ratio,
                           optimal_volume(chosen))[0]
        if known.is_file():
            return None
        check_case(model, load, chosen.fea_mesh_size, chosen.fea_youngs_modulus_mpa,
                   chosen.fea_poisson_ratio)
    except LoadCaseError as exc:
        return str(exc)
    except ModelError:
        return None
    return None


def _identity(path: Path) -> Identity | None:
    try:
        info = os.lstat(path)
    except OSError:
        return None
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)


class LoadChecks:
    """Load-case checks begun while a model and its case settle (:meth:`begin`), and
    the check a job's intake waits for (:meth:`refusal`): the one begun early when
    neither file nor the settings changed since it began, else a check made now."""

    def __init__(self, cache: Path) -> None:
        self.cache = cache
        # model -> (identities of model and case, settings, the check's future)
        self._ahead: dict[Path, tuple[tuple[Identity | None, Identity | None],
                                      dict[str, object], asyncio.Future[str | None]]] = {}

    def begin(self, model: Path, load: Path, settings: dict[str, object]) -> None:
        """Begin checking ``load`` against ``model`` in a worker thread (once per version
        of the two files and the settings)."""
        for gone in [path for path in self._ahead if not path.exists()]:
            del self._ahead[gone]  # files removed before they were taken
        key = (_identity(model), _identity(load))
        held = self._ahead.get(model)
        if held is not None and held[0] == key and held[1] == settings:
            return
        future = asyncio.ensure_future(
            asyncio.to_thread(refusal, model, load, dict(settings), self.cache))
        future.add_done_callback(_quiet)
        self._ahead[model] = (key, dict(settings), future)

    async def refusal(self, model: Path, load: Path, settings: dict[str, object]) -> str | None:
        """Why the job of ``model`` is refused for its case ``load`` (see :func:`refusal`),
        or None."""
        held = self._ahead.pop(model, None)
        if held is not None:
            key, chosen, future = held
            if key == (_identity(model), _identity(load)) and chosen == settings:
                try:
                    return await future
                except Exception:  # checked again below, where the error is reported
                    log.debug("early check of %s failed", load.name, exc_info=True)
        return await asyncio.to_thread(refusal, model, load, settings, self.cache)


def _quiet(future: asyncio.Future[str | None]) -> None:
    """Retrieve an abandoned check's outcome so that nothing is logged for it."""
    if not future.cancelled():
        future.exception()
