"""Taking a settled file into the job store, and ending jobs in done/ or failed/."""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import shutil
import stat
import tomllib
import uuid
from pathlib import Path

from hostd.config import Config, ConfigError, slicing_settings
from hostd.jobfolder import free_stem, leaves_folder, move, split_name, write_text
from hostd.jobstore import Job, JobStore
from hostd.status import StatusHub

log = logging.getLogger("hostd.intake")


class Rejected(Exception):
    """A dropped file that cannot become a printable job; the message says why."""


class Intake:
    """Turns settled files into queued jobs, and moves finished jobs to their outcome."""

    def __init__(self, config: Config, store: JobStore, hub: StatusHub) -> None:
        self.config = config
        self.store = store
        self.hub = hub
        self.jobs_folder = config.jobs.folder
        self.area = config.state.folder / "jobs"

    async def take(self, path: Path) -> Job | None:
        """Check ``path`` and queue it as a job, or send it to failed/ with the reason."""
        stem, suffix = split_name(path.name)
        override = path.with_name(f"{stem}.toml")
        kind = suffix.lstrip(".")
        try:
            self._check(path)
            settings = self._settings(override) if kind == "stl" else {}
            digest = await asyncio.to_thread(_sha256, path)
        except Rejected as exc:
            job = self.store.add(path.name, str(path), str(path), kind, "", {})
            self.fail(job, str(exc), extra=[override] if override.exists() else [])
            return None
        incoming = self.area / f"incoming-{uuid.uuid4().hex}"
        incoming.mkdir(parents=True)
        staged = move(path, incoming / path.name)
        if override.is_file() and not override.is_symlink():
            move(override, incoming / override.name)
        job = self.store.add(path.name, str(path), str(staged), kind, digest, settings)
        home = move(incoming, self.area / job.id)
        job = self.store.set_path(job.id, str(home / path.name))
        log.info("job %s: %s queued (sha256 %s)", job.id, job.name, digest[:12])
        self.hub.event("queued", id=job.id, name=job.name)
        return job

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
        """The job's slicing settings (flat keys): the config's, with NAME.toml applied."""
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
            settings = slicing_settings(values, base, "")
        except ConfigError as exc:
            raise Rejected(f"{override.name}: {exc}") from exc
        return settings.to_mapping()

    def fail(
        self, job: Job, reason: str, extra: list[Path] | None = None, state: str = "failed"
    ) -> Path:
        """Move the job's model to failed/NAME.* with NAME.error.txt; record and announce.

        ``state`` is the job's final state: ``failed``, or ``cancelled`` for a job
        stopped by a command (its files go to failed/ too, with the reason).
        """
        folder = self.jobs_folder / "failed"
        stem, suffix = split_name(job.name)
        free = free_stem(folder, stem)
        model = Path(job.path)
        if model.exists() or model.is_symlink():
            move(model, folder / f"{free}{suffix}")
        for path in extra or []:
            move(path, folder / f"{free}{path.suffix}")
        error = write_text(folder / f"{free}.error.txt", reason.rstrip() + "\n")
        self._drop_area(job)
        current = self.store.get(job.id)
        if current.state not in ("failed", "done", "cancelled"):
            self.store.transition(job.id, state, note=reason, error=reason, outcome=str(error))
        log.error("job %s %s: %s: %s", job.id, job.name, state, reason)
        self.hub.event(state, id=job.id, name=job.name, reason=reason)
        return error

    def finish(self, job: Job, gcode: Path, summary: str, cancelled: bool = False) -> Path:
        """Move the model and its G-code to done/NAME.* with NAME.summary.txt."""
        folder = self.jobs_folder / "done"
        stem, suffix = split_name(job.name)
        free = free_stem(folder, stem)
        model = Path(job.path)
        if suffix == ".gcode":
            target = move(gcode, folder / f"{free}.gcode")
            model.unlink(missing_ok=True)
        else:
            if model.exists():
                move(model, folder / f"{free}{suffix}")
            target = move(gcode, folder / f"{free}.gcode")
            override = model.with_name(f"{model.stem}.toml")
            if override.exists():
                move(override, folder / f"{free}.toml")
        write_text(folder / f"{free}.summary.txt", summary)
        self._drop_area(job)
        return target

    def _drop_area(self, job: Job) -> None:
        home = self.area / job.id
        if home.is_dir():
            shutil.rmtree(home, ignore_errors=True)

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


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
