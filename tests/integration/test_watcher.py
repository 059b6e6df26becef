"""Job folder watcher and intake: settle time, ignored names, collisions, refusals."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import os
import shutil
import time
from pathlib import Path

from support.waiting import until

from hostd.config import load_config
from hostd.jobs.filecheck import open_for_writing
from hostd.jobs.intake import Intake
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstore import JobStore
from hostd.jobs.watcher import _STAMP_GRAIN_S, Watcher, _changed_at
from hostd.publishing.status import StatusHub

DATA = Path(__file__).resolve().parents[1] / "data"
CUBE = DATA / "cube20_xyz.stl"


def make_config(tmp_path: Path, extra: str = "", settle: float = 0.2):
    path = tmp_path / "hostd.toml"
    path.write_text(f"[jobs]\nsettle_s = {settle}\n{extra}\n")
    return load_config(path, cwd=tmp_path)


SENTINEL = "zz-sentinel.gcode"


async def watch_for(config, jobs: int, action, sentinel: bool = False,
                    timeout: float = 20.0) -> tuple[list[str], JobStore]:
    """Run a watcher + intake while ``action(jobs_folder)`` runs, until ``jobs`` are recorded.

    With ``sentinel``, a last G-code file is dropped after the action and waited for too
    (and left out of the result): files the watcher was to leave alone had every chance
    to be taken by then.
    """
    store = JobStore(config.state.folder / "jobs.sqlite3")
    intake = Intake(config, JobLife(store, StatusHub()))
    taken: list[str] = []

    async def on_settled(path: Path) -> None:
        taken.append(path.name)
        await intake.take(path)

    stop = asyncio.Event()
    watcher = Watcher(config.jobs.folder, config.jobs.settle_s, on_settled)
    task = asyncio.create_task(watcher.run(stop))
    await until(lambda: config.jobs.folder.is_dir(), timeout)
    await action(config.jobs.folder)
    if sentinel:
        (config.jobs.folder / SENTINEL).write_text("G28\n")
        jobs += 1
    await until(lambda: len(store.jobs()) >= jobs, timeout)
    stop.set()
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task
    if sentinel:
        taken.remove(SENTINEL)
    return taken, store


def test_a_growing_file_is_taken_only_once_it_settled(tmp_path: Path) -> None:
    config = make_config(tmp_path, settle=1.0)
    data = CUBE.read_bytes()
    seen_early: list[bool] = []

    async def grow(folder: Path) -> None:
        target = folder / "slow.stl"
        with open(target, "wb") as handle:
            for start in range(0, len(data), len(data) // 5 + 1):
                handle.write(data[start:start + len(data) // 5 + 1])
                handle.flush()
                await asyncio.sleep(0.2)
                seen_early.append(target.exists())
        # every chunk came 0.2 s apart, well under the settle time: still in the folder
        assert all(seen_early)

    taken, store = asyncio.run(watch_for(config, 1, grow))
    assert taken == ["slow.stl"]
    (job,) = store.jobs()
    assert job.state == "queued"
    assert Path(job.path).read_bytes() == data
    assert Path(job.path).parent == config.state.folder / "jobs" / job.id


def test_hidden_and_temporary_files_are_ignored(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    names = [".part.stl", "part.stl.part", "part.stl~", "part.stl.swp", "part.stl.tmp",
             "notes.txt", "part.obj"]

    async def drop(folder: Path) -> None:
        for name in names:
            shutil.copyfile(CUBE, folder / name)

    taken, store = asyncio.run(watch_for(config, 0, drop, sentinel=True))
    assert taken == []
    assert [job.name for job in store.jobs()] == [SENTINEL]
    assert sorted(p.name for p in config.jobs.folder.iterdir() if p.is_file()) == sorted(names)


def test_files_present_at_start_are_taken_by_the_initial_scan(tmp_path: Path) -> None:
    config = make_config(tmp_path)
    config.jobs.folder.mkdir(parents=True)
    shutil.copyfile(CUBE, config.jobs.folder / "early.stl")
    (config.jobs.folder / "early.gcode").write_text("G28\nG1 X1\n")

    async def nothing(folder: Path) -> None:
        return None

    taken, store = asyncio.run(watch_for(config, 2, nothing))
    assert sorted(taken) == ["early.gcode", "early.stl"]
    assert sorted(job.kind for job in store.jobs()) == ["gcode", "stl"]


def test_same_name_twice_becomes_two_jobs(tmp_path: Path) -> None:
    config = make_config(tmp_path)

    async def drop_twice(folder: Path) -> None:
        shutil.copyfile(CUBE, folder / "part.stl")
        await until(lambda: not (folder / "part.stl").exists(), 10)
        shutil.copyfile(CUBE, folder / "part.stl")

    taken, store = asyncio.run(watch_for(config, 2, drop_twice))
    assert taken == ["part.stl", "part.stl"]
    jobs = store.jobs()
    assert [job.name for job in jobs] == ["part.stl", "part.stl"]
    assert len({job.path for job in jobs}) == 2
    assert all(Path(job.path).exists() for job in jobs)


def test_refusals_end_in_failed_with_a_reason(tmp_path: Path) -> None:
    config = make_config(tmp_path, extra="max_bytes = 2000")
    outside = tmp_path / "outside.stl"
    shutil.copyfile(DATA / "cube20_xyz.stl", outside)

    async def drop(folder: Path) -> None:
        os.symlink(outside, folder / "escape.stl")
        (folder / "empty.stl").write_bytes(b"")
        (folder / "dir.stl").mkdir()
        (folder / "big.stl").write_bytes(b"x" * 5000)
        (folder / "tuned.toml").write_text("infill.density = 3\n")
        (folder / "tuned.stl").write_bytes(b"solid x\nendsolid x\n")
        (folder / "typo.toml").write_text("[infill]\ndensiti = 0.3\n")
        (folder / "typo.stl").write_bytes(b"solid x\nendsolid x\n")
        (folder / "garbled.toml").write_text("infill = [\n")
        (folder / "garbled.stl").write_bytes(b"solid x\nendsolid x\n")

    _taken, store = asyncio.run(watch_for(config, 7, drop))
    failed = config.jobs.folder / "failed"
    reasons = {p.name: p.read_text() for p in failed.glob("*.error.txt")}
    assert "outside the job folder" in reasons["escape.error.txt"]
    assert "empty (0 bytes)" in reasons["empty.error.txt"]
    assert "is a directory" in reasons["dir.error.txt"]
    assert "over the limit of 2000 bytes" in reasons["big.error.txt"]
    assert "infill.density" in reasons["tuned.error.txt"]
    assert "infill.densiti" in reasons["typo.error.txt"]
    assert "not valid TOML" in reasons["garbled.error.txt"]
    assert (failed / "escape.stl").is_symlink()  # the link moved, its target untouched
    assert outside.exists()
    assert (failed / "dir.stl").is_dir()
    assert (failed / "tuned.toml").exists()
    assert {job.state for job in store.jobs()} == {"failed"}
    assert len(store.jobs()) == 7


def test_a_good_override_is_applied_and_kept_with_the_job(tmp_path: Path) -> None:
    config = make_config(tmp_path)

    async def drop(folder: Path) -> None:
        (folder / "dense.toml").write_text(
            "nozzle_temp = 200\n[infill]\ndensity = 0.6\nfield = 'wave'\n"
        )
        shutil.copyfile(CUBE, folder / "dense.stl")

    _taken, store = asyncio.run(watch_for(config, 1, drop))
    (job,) = store.jobs()
    assert job.settings["infill.density"] == 0.6
    assert job.settings["infill.field"] == "wave"
    assert (Path(job.path).parent / "dense.toml").exists()
    assert not (config.jobs.folder / "dense.toml").exists()


def test_a_link_inside_the_folder_is_taken_as_a_copy(tmp_path: Path) -> None:
    config = make_config(tmp_path)

    async def drop(folder: Path) -> None:
        library = folder / "library"
        library.mkdir()
        shutil.copyfile(CUBE, library / "cube.stl")
        os.symlink(library / "cube.stl", folder / "linked.stl")

    _taken, store = asyncio.run(watch_for(config, 1, drop))
    (job,) = store.jobs()
    assert job.state == "queued"
    assert not Path(job.path).is_symlink()
    assert Path(job.path).read_bytes() == CUBE.read_bytes()
    assert (config.jobs.folder / "library" / "cube.stl").exists()
    assert not (config.jobs.folder / "linked.stl").is_symlink()


def test_a_copy_that_stalls_longer_than_the_settle_time_is_waited_for(tmp_path: Path) -> None:
    config = make_config(tmp_path, settle=0.3)
    data = CUBE.read_bytes()
    half = len(data) // 2
    still_there: list[bool] = []

    async def stalled_copy(folder: Path) -> None:
        target = folder / "stalled.stl"
        with open(target, "wb") as handle:
            handle.write(data[:half])
            handle.flush()
            # the writer stalls with the file open, five settle times long
            await asyncio.sleep(5 * config.jobs.settle_s)
            still_there.append(target.exists())
            handle.write(data[half:])

    taken, store = asyncio.run(watch_for(config, 1, stalled_copy))
    assert still_there == [True]  # settled, but not taken while its writer held it open
    assert taken == ["stalled.stl"]
    (job,) = store.jobs()
    assert Path(job.path).read_bytes() == data
    assert job.sha256 == hashlib.sha256(data).hexdigest()


def test_writers_are_found_under_proc_and_readers_are_not(tmp_path: Path) -> None:
    path = tmp_path / "model.stl"
    path.write_bytes(b"solid x\n")
    assert not open_for_writing(path)
    with open(path, "rb"):
        assert not open_for_writing(path)
    with open(path, "ab") as handle:
        assert open_for_writing(path)
        moved = path.rename(tmp_path / "moved.stl")  # the same file under another name
        assert open_for_writing(moved)
        handle.write(b"endsolid x\n")
    assert not open_for_writing(moved)


def test_files_stamped_in_one_tick_settle_together_however_late_each_is_looked_at():
    # a file looked at within a tick of its stamp and one looked at later must get the
    # same settle start, else the later-stamped file can settle (and be queued) first
    stamp = time.time_ns()
    signature = (10, stamp, 0o100644, stamp)
    early = _changed_at(signature, time.monotonic(), 1.0)
    while time.time() < stamp / 1e9 + 3 * _STAMP_GRAIN_S:
        time.sleep(0.001)
    late = _changed_at(signature, time.monotonic(), 1.0)
    assert abs(late - early) < 0.001
