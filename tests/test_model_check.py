"""A model that changes after it was taken is noticed before slicing."""

from __future__ import annotations

import asyncio
import hashlib
from pathlib import Path

import pytest

from hostd.config import load_config
from hostd.intake import Intake
from hostd.jobstore import JobStore
from hostd.printjob import PrintJob
from hostd.status import StatusHub
from slicer.errors import ModelError

DATA = Path(__file__).parent / "data"
CUBE = DATA / "cube20_xyz.stl"


def setup(tmp_path: Path, taken: bytes):
    config_path = tmp_path / "hostd.toml"
    config_path.write_text("[jobs]\nsettle_s = 0.2\n")
    config = load_config(config_path, cwd=tmp_path)
    store = JobStore(config.state.folder / "jobs.sqlite3")
    model = tmp_path / "part.stl"
    model.write_bytes(taken)
    job = store.add("part.stl", str(model), str(model), "stl",
                    hashlib.sha256(taken).hexdigest(), {})
    hub = StatusHub()
    return config, store, hub, model, job


def test_a_model_written_on_after_it_was_taken_is_waited_for_then_started_over(
    tmp_path: Path,
) -> None:
    data = CUBE.read_bytes()
    half = len(data) // 2
    config, store, hub, model, job = setup(tmp_path, data[:half])

    async def main() -> tuple[str, bool]:
        printjob = PrintJob(job, config, store, hub, Intake(config, store, hub), executor=None)
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
    printjob = PrintJob(job, config, store, hub, Intake(config, store, hub), executor=None)
    assert asyncio.run(printjob.check_model(job, resume=True)) == job
    model.write_bytes(data + b"\n")
    with pytest.raises(ModelError, match="changed after it was taken"):
        asyncio.run(printjob.check_model(job, resume=True))
    assert store.get(job.id).sha256 == job.sha256
