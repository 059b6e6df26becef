"""Outcomes are recorded before files move; a crash in between is finished at the next start."""

from __future__ import annotations

import asyncio
import shutil
from pathlib import Path

from hostd.config import load_config
from hostd.jobs.intake import Intake
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstore import JobStore
from hostd.publishing.status import StatusHub

DATA = Path(__file__).resolve().parents[1] / "data"


def taken_job(tmp_path: Path, name: str = "part.stl"):
    config = load_config(None, cwd=tmp_path)
    store = JobStore(config.state.folder / "jobs.sqlite3")
    intake = Intake(config, JobLife(store, StatusHub()))
    config.jobs.folder.mkdir(parents=True)
    shutil.copyfile(DATA / "cube20_xyz.stl", config.jobs.folder / name)
    job = asyncio.run(intake.take(config.jobs.folder / name))
    return config, store, intake, job


def test_done_recorded_then_crash_before_moving_is_finished_at_start(tmp_path: Path) -> None:
    config, store, intake, job = taken_job(tmp_path)
    home = Path(job.path).parent
    (home / "part.gcode").write_text("G28\n")
    (home / "part.summary.txt").write_text("summary\n")
    (home / "part.gcode.part").write_text("G28\n")
    # a crash right after the outcome was recorded: the files are still in the job's folder
    store.transition(job.id, "slicing")
    store.transition(job.id, "printing")
    target = intake.outcomes._record(store.get(job.id), "done", "done", None)
    assert store.get(job.id).state == "done"
    assert list((config.jobs.folder / "done").glob("*")) == []

    reopened = Intake(config, JobLife(JobStore(config.state.folder / "jobs.sqlite3"),
                                       StatusHub()))
    reopened.outcomes.settle()
    done = config.jobs.folder / "done"
    assert target == done / "part"
    assert sorted(p.name for p in done.iterdir()) == ["part.gcode", "part.stl", "part.summary.txt"]
    assert not home.exists()


def test_failed_outcomes_never_overwrite(tmp_path: Path) -> None:
    config, store, intake, first = taken_job(tmp_path)
    intake.fail(first, "first reason")
    shutil.copyfile(DATA / "cube20_xyz.stl", config.jobs.folder / "part.stl")
    second = asyncio.run(intake.take(config.jobs.folder / "part.stl"))
    intake.fail(second, "second reason", state="cancelled")
    failed = config.jobs.folder / "failed"
    assert (failed / "part.error.txt").read_text() == "first reason\n"
    assert (failed / "part-1.error.txt").read_text() == "second reason\n"
    assert (failed / "part.stl").exists()
    assert (failed / "part-1.stl").exists()
    assert store.get(first.id).state == "failed"
    assert store.get(second.id).state == "cancelled"
    assert store.get(second.id).outcome == str(failed / "part-1")
