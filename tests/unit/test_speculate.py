"""The whole-model pass made while a file settles: taken only by the very same file."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

from support.paths import DATA

from hostd.jobs.speculate import MadeAhead, Speculation
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

BED = (220.0, 220.0, 250.0)


def dropped(tmp_path: Path) -> Path:
    path = tmp_path / "jobs" / "cube.stl"
    path.parent.mkdir()
    path.write_bytes((DATA / "cube20_xyz.stl").read_bytes())
    return path


def test_the_plan_made_ahead_follows_the_file_into_its_job_folder(tmp_path) -> None:
    path = dropped(tmp_path)
    settings = SliceSettings()

    async def scenario() -> MadeAhead | None:
        ahead = Speculation()
        assert ahead.begin(path, settings, BED)
        assert not ahead.begin(path, settings, BED)  # once per version of the file
        moved = tmp_path / "job-1" / path.name
        moved.parent.mkdir()
        os.replace(path, moved)  # what the intake does; the pass may still be reading
        return await ahead.take(moved, settings, BED)

    made = asyncio.run(scenario())
    assert made is not None
    plan, seconds, first_layer = made
    assert seconds >= 0.0
    fresh = SlicePlan.from_file(DATA / "cube20_xyz.stl", settings, BED)
    assert [plan.layer_gcode(i) for i in range(plan.layer_count)] == [
        fresh.layer_gcode(i) for i in range(fresh.layer_count)]
    # layer 0 was made ahead too, as the job's own slicing makes it
    assert first_layer is not None
    assert first_layer.lines == fresh.layer_gcode(0)


def test_a_changed_file_or_other_settings_are_sliced_again(tmp_path) -> None:
    path = dropped(tmp_path)
    settings = SliceSettings()

    async def scenario() -> list[object]:
        ahead = Speculation()
        ahead.begin(path, settings, BED)
        with open(path, "ab") as handle:  # the writer was not done
            handle.write(b"\0" * 50)
        after_change = await ahead.take(path, settings, BED)
        ahead.begin(path, settings, BED)
        other = SliceSettings.from_mapping({"infill.density": 0.5})
        other_settings = await ahead.take(path, other, BED)
        ahead.begin(path, settings, BED)
        ahead.forget()
        forgotten = await ahead.take(path, settings, BED)
        stress = SliceSettings.from_mapping({"infill.field": "stress"})
        return [after_change, other_settings, forgotten, ahead.begin(path, stress, BED)]

    assert asyncio.run(scenario()) == [None, None, None, False]
