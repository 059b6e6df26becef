"""The layer schedule: retunes and cancelled bodies per layer, rebuilt identically for a resume."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from hostd.jobs.schedule import LayerSchedule
from slicer.output.gcode import LayerCode
from slicer.plan import SlicePlan
from slicer.settings import SettingsError, SliceSettings


@pytest.fixture(scope="module")
def plan(tmp_path_factory) -> SlicePlan:
    path: Path = tmp_path_factory.mktemp("models") / "pair.stl"
    left = trimesh.creation.box((15.0, 15.0, 4.0))
    left.apply_translation((-15.0, 0.0, 2.0))
    right = trimesh.creation.box((15.0, 15.0, 4.0))
    right.apply_translation((15.0, 0.0, 2.0))
    trimesh.util.concatenate([left, right]).export(path)
    return SlicePlan.from_file(path, SliceSettings())


def test_retunes_apply_from_their_layer_and_rebuild_identically(plan: SlicePlan) -> None:
    base = SliceSettings()
    schedule = LayerSchedule(plan, base)
    before = [schedule.layer_gcode(i) for i in range(plan.layer_count)]
    schedule.retune(6, {"nozzle_temp": 230, "fan_speed": 0.5})
    schedule.retune(9, {"infill.density": 0.5})
    schedule.cancel_body(1, 12)
    assert schedule.settings_at(5) == base
    at6, at9 = schedule.settings_at(6), schedule.settings_at(9)
    assert (at6.nozzle_temp, at6.infill_density) == (230, 0.2)
    assert (at9.nozzle_temp, at9.infill_density) == (230, 0.5)
    assert schedule.excluded_at(11) == frozenset()
    assert schedule.excluded_at(12) == {1}

    after = [schedule.layer_gcode(i) for i in range(plan.layer_count)]
    assert after[:6] == before[:6]
    assert after[6][:4] == [";LAYER:6", ";RETUNE", "M104 S230", "M106 S128"]
    assert all("M104 S230" not in after[i] for i in range(7, plan.layer_count))
    assert after[12] == plan.with_settings(schedule.settings_at(12)).layer_gcode(12, frozenset({1}))
    assert len(after[12]) < len(before[12])

    rebuilt = LayerSchedule(plan, base, schedule.changes, schedule.cancelled)
    assert [rebuilt.layer_gcode(i) for i in range(plan.layer_count)] == after


def test_retunes_that_change_the_geometry_or_break_a_range_are_refused(plan: SlicePlan) -> None:
    schedule = LayerSchedule(plan, SliceSettings())
    with pytest.raises(SettingsError):
        schedule.retune(3, {"layer_height": 0.3})
    with pytest.raises(SettingsError):
        schedule.retune(3, {"infill.density": 2.0})
    with pytest.raises(SettingsError):
        schedule.retune(3, {"no_such_key": 1})
    assert schedule.changes == []


def test_a_layer_made_ahead_is_used_once_and_only_if_sliced_as_then(plan: SlicePlan) -> None:
    made = plan.layer_code(0)
    marked = LayerCode([*made.lines, ";MADE AHEAD"], made.filament_mm, made.time_s, made.z_line)
    schedule = LayerSchedule(plan, SliceSettings())
    schedule.made_ahead(0, marked)
    assert schedule.layer_gcode(0) == marked.lines
    assert schedule.layer_gcode(0) == made.lines  # once: then sliced as usual
    schedule.made_ahead(0, marked)
    schedule.cancel_body(1, 0)  # layer 0 no longer has every body
    without = schedule.layer_gcode(0)
    assert ";MADE AHEAD" not in without
    assert without != made.lines
    retuned = LayerSchedule(plan, SliceSettings())
    retuned.made_ahead(0, marked)
    retuned.retune(0, {"infill.density": 0.5})
    assert ";MADE AHEAD" not in retuned.layer_gcode(0)
