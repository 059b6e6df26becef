"""A model that changes after it was taken is noticed before slicing (its size and hash
checked again), and one still being written when it is copied into the state folder is not
taken."""

from __future__ import annotations

import asyncio
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from hostd.config import load_config
from hostd.jobs import intake as intake_module
from hostd.jobs.filecheck import fingerprint
from hostd.jobs.intake import Intake
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstore import JobStore
from hostd.printing.activejob import ActiveJob
from hostd.printing.printjob import PrintJob
from hostd.publishing.status import StatusHub
from slicer.errors import ModelError

DATA = Path(__file__).resolve().parents[1] / "data"
CUBE = DATA / "cube20_xyz.stl"


def print_job(config, store: JobStore, hub: StatusHub, job) -> PrintJob:
    """The daemon's run of ``job`` (not started)."""
    life = JobLife(store, hub)
    return PrintJob(ActiveJob(job, life), config, Intake(config, life), executor=None)


def setup(tmp_path: Path, taken: bytes, state: Path | None = None):
    config_path = tmp_path / "hostd.toml"
    folder = f'[state]\nfolder = "{state}"\n' if state is not None else ""
    config_path.write_text("[jobs]\nsettle_s = 0.2\n" + folder)
    config = load_config(config_path, cwd=tmp_path)
    store = JobStore(config.state.folder / "jobs.sqlite3")
    model = tmp_path / "part.stl"
    model.write_bytes(taken)
    job = store.add("part.stl", str(model), str(model), "stl",
                    hashlib.sha256(taken).hexdigest(), {}, size=len(taken))
    hub = StatusHub()
    return config, store, hub, model, job


def test_a_model_written_on_after_it_was_taken_is_waited_for_then_started_over(
    tmp_path: Path,
) -> None:
    data = CUBE.read_bytes()
    half = len(data) // 2
    config, store, hub, model, job = setup(tmp_path, data[:half])

    async def main() -> tuple[str, bool]:
        printjob = print_job(config, store, hub, job)
        with open(model, "ab") as writer:  # the copy goes on after the file was taken
            check = asyncio.create_task(printjob.check_model(job, resume=False))
            writer.write(data[half:])
            writer.flush()
            # the writer stalls, file open, well past the settle time: no slicing yet
            await asyncio.sleep(5 * config.jobs.settle_s)
            waited = not check.done()
        checked = await asyncio.wait_for(check, 20)
        return checked.sha256, waited

    sha256, waited = asyncio.run(main())
    assert waited
    assert sha256 == hashlib.sha256(data).hexdigest() == store.get(job.id).sha256


def test_an_unchanged_model_passes_and_a_resumed_one_that_changed_fails(tmp_path: Path) -> None:
    data = CUBE.read_bytes()
    config, store, hub, model, job = setup(tmp_path, data)
    printjob = print_job(config, store, hub, job)
    assert asyncio.run(printjob.check_model(job, resume=True)) == job
    model.write_bytes(data + b"\n")
    with pytest.raises(ModelError, match="changed after it was taken"):
        asyncio.run(printjob.check_model(job, resume=True))
    assert store.get(job.id).sha256 == job.sha256


def test_a_model_that_grew_after_its_hash_was_read_is_noticed_by_its_size(
    tmp_path: Path,
) -> None:
    data = CUBE.read_bytes()
    config, store, hub, model, job = setup(tmp_path, data)
    printjob = print_job(config, store, hub, job)
    read = fingerprint(model)  # hashed beside the whole-model pass: the bytes taken
    assert (read.size, read.sha256) == (job.size, job.sha256)
    with open(model, "ab") as writer:  # then the writer went on, and stopped
        writer.write(b"solid more\n")
    checked = asyncio.run(printjob.check_model(job, resume=False, digest=read))
    assert checked is not job  # started over from the complete file
    assert (checked.size, checked.sha256) == (len(data) + 11, fingerprint(model).sha256)
    assert (store.get(job.id).size, store.get(job.id).sha256) == (checked.size, checked.sha256)
    with pytest.raises(ModelError, match="changed after it was taken"):
        asyncio.run(printjob.check_model(job, resume=True, digest=read))


@pytest.fixture
def other_disk(tmp_path: Path) -> Path:
    """A state folder on another filesystem than the job folder (tmpfs)."""
    shm = Path("/dev/shm")
    if not shm.is_dir() or os.stat(shm).st_dev == os.stat(tmp_path).st_dev:
        pytest.skip("needs /dev/shm on another filesystem")
    folder = Path(tempfile.mkdtemp(prefix="hostd-state-", dir=shm))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def test_across_filesystems_a_model_still_open_for_writing_is_not_taken(
    tmp_path: Path, other_disk: Path,
) -> None:
    data = CUBE.read_bytes()
    config, store, hub, _model, _job = setup(tmp_path, b"", other_disk)
    intake = Intake(config, JobLife(store, hub))
    dropped = config.jobs.folder / "part.stl"
    dropped.parent.mkdir(parents=True, exist_ok=True)
    with open(dropped, "wb") as writer:  # a writer the settle time did not wait out
        writer.write(data)
        writer.flush()
        assert asyncio.run(intake.take(dropped)) is None
        assert dropped.read_bytes() == data  # left where it was, nothing half-copied
        assert not list((other_disk / "jobs").glob("incoming-*/*"))
    job = asyncio.run(intake.take(dropped))  # closed: taken, as a checked copy
    assert job is not None
    assert not dropped.exists()
    assert Path(job.path).read_bytes() == data
    assert (job.size, job.sha256) == (len(data), hashlib.sha256(data).hexdigest())


def test_across_filesystems_a_model_written_on_after_its_hash_is_not_taken(
    tmp_path: Path, other_disk: Path, monkeypatch,
) -> None:
    data = CUBE.read_bytes()
    config, store, hub, _model, _job = setup(tmp_path, b"", other_disk)
    intake = Intake(config, JobLife(store, hub))
    dropped = config.jobs.folder / "part.stl"
    dropped.parent.mkdir(parents=True, exist_ok=True)
    dropped.write_bytes(data[:1000])
    hashed = fingerprint

    def then_written_on(path: Path):
        read = hashed(path)
        if path == dropped and dropped.stat().st_size < len(data):
            with open(dropped, "ab") as writer:  # opened, written and closed again at once
                writer.write(data[1000:])
        return read

    monkeypatch.setattr(intake_module, "fingerprint", then_written_on)
    recorded = len(store.jobs())
    assert asyncio.run(intake.take(dropped)) is None
    assert dropped.read_bytes() == data  # the writer's bytes are all still there
    assert not list((other_disk / "jobs").glob("incoming-*/*"))
    assert len(store.jobs()) == recorded  # no job for it yet
    job = asyncio.run(intake.take(dropped))  # taken once it held still
    assert job is not None
    assert Path(job.path).read_bytes() == data
    assert (job.size, job.sha256) == (len(data), hashlib.sha256(data).hexdigest())
