"""Ending jobs in done/ or failed/: recorded first, then files moved, finished again at start."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

from hostd.jobs.jobfolder import free_stem, move, split_name, write_text
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import FINAL_STATES, Done, JobState, ended
from hostd.jobs.jobstore import Job

log = logging.getLogger("hostd.jobs.outcomes")


class Outcomes:
    """Moves a finished job's files out of its folder in the state area.

    The outcome (state, reason, and the name chosen in done/ or failed/) is
    recorded in the job store before any file moves; a crash in between leaves
    the files in ``<state>/jobs/<id>/``, and :meth:`settle` moves them at the
    next start under the recorded name. Nothing is ever overwritten.
    """

    def __init__(self, jobs_folder: Path, area: Path, life: JobLife) -> None:
        self.jobs_folder = jobs_folder
        self.area = area
        self.store = life.store
        self.life = life

    def fail(
        self, job: Job, reason: str, extra: list[Path] | None = None, state: str = "failed"
    ) -> Path:
        """End the job in ``state`` (failed or cancelled): failed/NAME.* and NAME.error.txt."""
        stem = self._record(job, state, "failed", reason)
        target = self._move_out(job, stem, extra or [])
        error = write_text(target.with_name(f"{target.name}.error.txt"), reason.rstrip() + "\n")
        log.error("job %s %s: %s: %s", job.id, job.name, state, reason)
        self.life.publish(ended(JobState(state), job.id, job.name, reason))
        return error

    def finish(self, job: Job) -> Path:
        """End the job done: its folder's files (model, G-code, summary) to done/NAME.*."""
        stem = self._record(job, "done", "done", None)
        target = self._move_out(job, stem, [])
        gcode = target.with_name(f"{target.name}.gcode")
        log.info("job %s %s: done, G-code in %s", job.id, job.name, gcode)
        self.life.publish(Done(job.id, job.name, str(gcode)))
        return gcode

    def settle(self) -> None:
        """At start: move the files of jobs that ended while their files were moving."""
        if not self.area.is_dir():
            return
        for job in self.store.jobs(*FINAL_STATES):
            if (self.area / job.id).is_dir() and job.outcome:
                target = self._move_out(job, Path(job.outcome), [])
                if job.state != "done" and job.error:
                    write_text(target.with_name(f"{target.name}.error.txt"), job.error + "\n")
                log.info("job %s %s: files moved to %s", job.id, job.name, target.parent)

    def _record(self, job: Job, state: str, folder_name: str, reason: str | None) -> Path:
        """Choose the free name in done/ or failed/ and record the outcome; returns the stem."""
        folder = self.jobs_folder / folder_name
        stem, _suffix = split_name(job.name)
        target = folder / free_stem(folder, stem)
        current = self.store.get(job.id)
        if current.state in FINAL_STATES:
            return Path(current.outcome) if current.outcome else target
        self.life.end(job.id, JobState(state), reason, str(target))
        return target

    def _move_out(self, job: Job, target: Path, extra: list[Path]) -> Path:
        """Move the job's files to ``target`` + their suffixes; returns ``target``."""
        stem, suffix = split_name(job.name)
        home = self.area / job.id
        target.parent.mkdir(parents=True, exist_ok=True)
        if home.is_dir():
            for path in sorted(home.iterdir()):
                if path.name.endswith(".part") or not path.name.startswith(stem):
                    continue
                move(path, target.with_name(target.name + path.name[len(stem):]))
            shutil.rmtree(home, ignore_errors=True)
        else:  # refused before it was taken: still in the job folder
            model = Path(job.path)
            if model.exists() or model.is_symlink():
                move(model, target.with_name(target.name + suffix))
        for path in extra:  # NAME.toml, NAME.load.toml: each keeps its whole suffix
            tail = path.name[len(stem):] if path.name.startswith(stem) else path.suffix
            move(path, target.with_name(target.name + tail))
        return target
