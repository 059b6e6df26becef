"""Taking a settled file into the job store, and ending jobs in done/ or failed/."""

from __future__ import annotations

import asyncio
import logging
import os
import shutil
import stat
import tomllib
import uuid
from pathlib import Path

from hostd.config import Config
from hostd.jobs.filecheck import Fingerprint, fingerprint, open_for_writing
from hostd.jobs.jobfolder import LOAD_SUFFIX, free_stem, leaves_folder, move, split_name
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import Queued
from hostd.jobs.jobstore import Job
from hostd.jobs.loadcheck import LoadChecks, load_analysis_modules
from hostd.jobs.outcomes import Outcomes
from slicer.fea.material import file_settings
from slicer.settings import SettingsError

log = logging.getLogger("hostd.jobs.intake")


class Rejected(Exception):
    """A dropped file that cannot become a printable job; the message says why."""


class Intake:
    """Turns settled files into queued jobs, and moves finished jobs to their outcome."""

    def __init__(self, config: Config, life: JobLife) -> None:
        """``life``: the daemon's one writer of job states (the store and snapshot's)."""
        self.config = config
        self.store = life.store
        self.life = life
        self.jobs_folder = config.jobs.folder
        self.area = config.state.folder / "jobs"
        self.outcomes = Outcomes(self.jobs_folder, self.area, life)
        self.load_checks = LoadChecks(config.state.folder / "fea")

    async def take(self, path: Path) -> Job | None:
        """Check ``path`` and queue it as a job, or send it to failed/ with the reason."""
        if path.name.lower().endswith(LOAD_SUFFIX):
            load_analysis_modules()  # its model's job will need them: load them meanwhile
            return self._lone_load(path)
        stem, suffix = split_name(path.name)
        override = path.with_name(f"{stem}.toml")
        load = path.with_name(f"{stem}{LOAD_SUFFIX}")
        kind = suffix.lstrip(".")
        try:
            self._check(path)
            settings = self._settings(override) if kind == "stl" else {}
            if kind == "stl" and (load.exists() or load.is_symlink()):
                reason = await self.load_checks.refusal(path, load, settings)
                if reason is not None:
                    raise Rejected(reason)
            digest = await asyncio.to_thread(fingerprint, path)
        except Rejected as exc:
            job = self.store.add(path.name, str(path), str(path), kind, "", {})
            extra = [p for p in (override, load) if p.exists() and p != path]
            self.fail(job, str(exc), extra=extra)
            return None
        incoming = self.area / f"incoming-{uuid.uuid4().hex}"
        try:
            staged = await asyncio.to_thread(
                _stage, path, override, load if kind == "stl" else None, incoming, digest
            )
        except StillWritten as exc:
            # left in the job folder: its writer's next change makes it settle again
            await asyncio.to_thread(shutil.rmtree, incoming, True)
            log.warning("%s; not taken yet", exc)
            return None
        job = self.store.add(path.name, str(path), str(staged), kind, digest.sha256, settings,
                             size=digest.size)
        home = move(incoming, self.area / job.id)
        job = self.store.set_path(job.id, str(home / path.name))
        log.info("job %s: %s queued (%d bytes, sha256 %s)", job.id, job.name, digest.size,
                 digest.sha256[:12])
        self.life.publish(Queued(job.id, job.name))
        return job

    def check_ahead(self, path: Path) -> None:
        """Begin checking the load case of a model that is settling (nothing for a model
        without one, or whose settings are refused: its take reports that)."""
        stem, suffix = split_name(path.name)
        load = path.with_name(f"{stem}{LOAD_SUFFIX}")
        if suffix != ".stl" or not load.is_file():
            return
        try:
            settings = self._settings(path.with_name(f"{stem}.toml"))
        except Rejected:
            return
        self.load_checks.begin(path, load, settings)

    def _lone_load(self, path: Path) -> None:
        """A settled load case: taken later with its model, or failed when there is none."""
        if not (path.exists() or path.is_symlink()):
            return None  # already taken with its model
        stem = path.name[: -len(LOAD_SUFFIX)]
        if any(split_name(p.name) == (stem, ".stl") for p in path.parent.iterdir()):
            return None  # its model's intake takes it
        job = self.store.add(path.name, str(path), str(path), "load", "", {})
        self.fail(job, f"{path.name}: its model {stem}.stl is missing: drop the model with it")
        return None

    def _check(self, path: Path) -> None:
        """Refuse links leaving the folder, non-files, unreadable, empty and huge files."""
        if leaves_folder(path, self.jobs_folder):
            raise Rejected(f"{path.name} is a link to {os.readlink(path)}, outside the job folder")
        try:
            info = path.stat()
        except OSError as exc:
            raise Rejected(f"cannot read {path.name}: {exc.strerror}") from exc
        if stat.S_ISDIR(info.st_mode):
            raise Rejected(f"{path.name} is a directory, not a file")
        if not stat.S_ISREG(info.st_mode):
            raise Rejected(f"{path.name} is not a regular file")
        if info.st_size == 0:
            raise Rejected(f"{path.name} is empty (0 bytes)")
        if info.st_size > self.config.jobs.max_bytes:
            raise Rejected(
                f"{path.name} is {info.st_size} bytes, over the limit of "
                f"{self.config.jobs.max_bytes} bytes (jobs.max_bytes)"
            )
        try:
            with open(path, "rb") as handle:
                handle.read(1)
        except OSError as exc:
            raise Rejected(f"cannot read {path.name}: {exc.strerror}") from exc

    def _settings(self, override: Path) -> dict[str, object]:
        """The job's slicing settings (flat keys): the config's, with NAME.toml applied
        (slicing keys and an optional ``[material]`` table, as ``hostd tailor`` reads)."""
        base = self.config.slicing
        if not override.exists():
            return base.to_mapping()
        if override.is_symlink() or not override.is_file():
            raise Rejected(f"{override.name} must be a plain file")
        try:
            values = tomllib.loads(override.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise Rejected(f"{override.name} is not valid TOML: {exc}") from exc
        try:
            settings = file_settings(values, base)
        except SettingsError as exc:
            raise Rejected(f"{override.name}: {exc}") from exc
        mapping = settings.to_mapping()
        field_file = str(mapping.get("infill.file") or "")
        if field_file and field_file != base.infill_file:
            # a file named by the job's own TOML is found beside it, in the job folder
            path = override.parent / Path(field_file).expanduser()
            if not path.is_file():
                raise Rejected(f"{override.name}: infill.file: no such file: {field_file}")
            mapping["infill.file"] = str(path.absolute())
        return mapping

    def fail(
        self, job: Job, reason: str, extra: list[Path] | None = None, state: str = "failed"
    ) -> Path:
        """End the job in failed/ with NAME.error.txt (``state`` failed or cancelled)."""
        return self.outcomes.fail(job, reason, extra, state)

    def finish(self, job: Job) -> Path:
        """End the job in done/ (model, G-code and summary); returns the G-code's path."""
        return self.outcomes.finish(job)

    def recover_incoming(self) -> None:
        """Put files of an interrupted take (crash mid-intake) back into the job folder."""
        if not self.area.is_dir():
            return
        owners = {Path(job.path).parent: job for job in self.store.jobs("queued")}
        for incoming in self.area.glob("incoming-*"):
            job = owners.get(incoming)
            if job is not None:  # recorded but not yet moved under its id
                home = move(incoming, self.area / job.id)
                self.store.set_path(job.id, str(home / Path(job.path).name))
                continue
            for path in incoming.iterdir():
                stem, suffix = split_name(path.name)
                target = self.jobs_folder / path.name
                if target.exists():
                    target = self.jobs_folder / f"{free_stem(self.jobs_folder, stem)}{suffix}"
                move(path, target)
            incoming.rmdir()


class StillWritten(Exception):
    """The model changed while it was being taken (a writer that kept writing)."""


def _stage(path: Path, override: Path, load: Path | None, incoming: Path,
           taken: Fingerprint) -> Path:
    """Move the model and its side files into ``incoming``; return the model's new path.

    On one filesystem the model is renamed (the file itself: a writer that goes on
    is caught by the size and hash checked again before slicing). Across two (the
    job folder and the state folder on different disks), and for a link inside the
    folder (taken as a copy of what it points to), it is copied: a file still open
    for writing is not copied, and the copy must have the length and hash ``taken``
    from the file, with the file unchanged meanwhile, before the file is removed;
    else StillWritten. The copy of a large file is why this runs in a thread. The
    load case is found beside the model when it is sliced.
    """
    incoming.mkdir(parents=True)
    staged = incoming / path.name
    if not path.is_symlink():
        try:
            os.replace(path, staged)
        except OSError:  # EXDEV: another filesystem (or one that cannot rename): copied
            pass
        else:
            return _stage_side_files(override, load, incoming, staged)
    _copy_checked(path, staged, taken)
    path.unlink()
    return _stage_side_files(override, load, incoming, staged)


def _copy_checked(path: Path, staged: Path, taken: Fingerprint) -> None:
    """Copy ``path`` to ``staged`` and check the copy holds what was ``taken``."""
    if open_for_writing(path):
        raise StillWritten(f"{path.name} is open for writing again")
    before = path.stat()
    shutil.copyfile(path, staged)
    after = path.stat()
    copied = fingerprint(staged)
    moved = (before.st_size, before.st_mtime_ns) != (after.st_size, after.st_mtime_ns)
    if copied != taken or moved:
        staged.unlink()
        raise StillWritten(f"{path.name} changed while it was taken ({taken.size} bytes "
                           f"hashed, {after.st_size} now)")


def _stage_side_files(override: Path, load: Path | None, incoming: Path, staged: Path) -> Path:
    if override.is_file() and not override.is_symlink():
        move(override, incoming / override.name)
    if load is not None and load.is_file() and not load.is_symlink():
        move(load, incoming / load.name)
    return staged
