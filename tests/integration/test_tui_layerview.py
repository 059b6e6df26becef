"""The daemon's side of the dashboard: one layer as polylines, field samples, estimates."""

from __future__ import annotations

import asyncio
import concurrent.futures
import json

import numpy as np
import pytest
from support.daemon_helpers import two_bodies
from support.paths import DATA

from drivers.link.protocol import strip_comment
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.sources import SlicedSource
from hostd.publishing.layerview import (
    estimate,
    field_samples,
    layer_view,
    parse_layer,
    sample_layers,
)
from slicer.plan import SlicePlan
from slicer.settings import SettingsError, SliceSettings


@pytest.fixture(scope="module")
def dogbone() -> LayerSchedule:
    plan = SlicePlan.from_file(DATA / "dogbone_100x30x5.stl", SliceSettings())
    return LayerSchedule(plan, SliceSettings())


def test_parse_layer_follows_the_gcode_command_by_command(dogbone: LayerSchedule) -> None:
    lines = dogbone.layer_gcode(8)
    paths, count = parse_layer(lines)
    commands = [c for c in map(strip_comment, lines) if c]
    assert count == len(commands)
    extruding = sum(1 for c in commands if c.startswith("G1") and " X" in c and " E" in c
                    and not c.split(" E")[1].startswith("-"))
    assert sum(len(coords) - 1 for _kind, coords, _end in paths) == extruding
    ends = [end for _kind, _coords, end in paths]
    assert ends == sorted(ends)
    assert 0 < ends[-1] <= count
    kinds = [kind for kind, _coords, _end in paths]
    assert kinds[0] == "WALL-OUTER"
    assert {"WALL-INNER", "FILL"} <= set(kinds)
    # each path's end is the command that draws its last point
    for _kind, coords, end in paths:
        x, y = coords[-1]
        assert f"X{x:.3f} Y{y:.3f}" in commands[end - 1]


def test_layer_view_is_json_simplified_and_framed_by_the_model(dogbone: LayerSchedule) -> None:
    exact = layer_view(dogbone, 8, tolerance=0.0)
    coarse = layer_view(dogbone, 8, tolerance=0.5)
    assert exact["layer"] == 8
    assert exact["layers"] == 25
    assert exact["z"] == pytest.approx(1.8)
    assert exact["bounds"] == pytest.approx(dogbone.base_plan.bounds, abs=0.01)
    assert len(coarse["paths"]) == len(exact["paths"])
    assert [p["end"] for p in coarse["paths"]] == [p["end"] for p in exact["paths"]]
    count = lambda view: sum(len(p["points"]) for p in view["paths"])  # noqa: E731
    assert count(coarse) < count(exact)
    assert json.loads(json.dumps(coarse)) == coarse
    assert exact["body_count"] == 1
    assert exact["bodies"] == []
    assert exact["field"] is None


def test_field_samples_cover_the_layer_only(dogbone: LayerSchedule) -> None:
    field = field_samples(dogbone, 8, 40, 12)
    values = np.asarray(field["values"])
    assert values.shape == (12, 40)
    assert field["name"] == "linear"
    inside = values >= 0
    assert inside.any()
    assert (~inside).any()
    assert values[inside].min() >= 0
    assert values[inside].max() <= 255
    assert values[inside].max() - values[inside].min() > 100  # a ramp, not a flat colour
    big = field_samples(dogbone, 8, 1000, 1000)
    assert big["columns"] * big["rows"] <= 40_000
    assert np.asarray(big["values"]).shape == (200, 200)


def test_estimate_and_a_retune_preview(dogbone: LayerSchedule) -> None:
    assert sample_layers(25) == [0, 3, 7, 10, 14, 17, 21, 24]
    now = estimate(dogbone, current=12, next_unsliced=15, eta_s=100.0)
    assert 0 < now["filament_used_mm"] < now["filament_total_mm"]
    assert now["settings"]["infill.density"] == 0.2
    assert "wave" in now["fields"]
    denser = estimate(dogbone, 12, 15, 100.0, {"infill.density": 0.6})
    assert denser["filament_total_mm"] == now["filament_total_mm"]
    new = denser["retuned"]
    assert new["filament_total_mm"] > now["filament_total_mm"]
    assert new["eta_s"] > 100.0
    assert new["time_ratio"] > 1.0
    assert dogbone.changes == []  # nothing applied
    with pytest.raises(SettingsError, match="layer_height"):
        estimate(dogbone, 12, 15, 100.0, {"layer_height": 0.3})


def test_a_cancelled_body_is_outlined_and_leaves_no_skin(tmp_path) -> None:
    plan = SlicePlan.from_file(two_bodies(tmp_path / "pair.stl"), SliceSettings())
    schedule = LayerSchedule(plan, SliceSettings())
    schedule.cancel_body(1, 2)
    before, after = layer_view(schedule, 1), layer_view(schedule, 3)
    assert [b["cancelled"] for b in before["bodies"]] == [False, False]
    assert [b["cancelled"] for b in after["bodies"]] == [False, True]
    assert after["cancelled"] == [{"object": 1, "from_layer": 2}]
    kept = np.concatenate([np.asarray(r) for r in after["bodies"][0]["rings"]])
    left_out = np.concatenate([np.asarray(r) for r in after["bodies"][1]["rings"]])
    middle = (kept[:, 0].max() + left_out[:, 0].min()) / 2
    for view, sides in ((before, 2), (after, 1)):  # bottom skin layers: SKIN paths
        assert any(p["kind"] == "SKIN" for p in view["paths"])
        xs = np.concatenate([np.asarray(p["points"])[:, 0] for p in view["paths"]])
        assert len({bool(xs.min() > middle), bool(xs.max() > middle)}) == sides


def test_a_layer_view_leaves_the_schedule_as_the_print_has_it(tmp_path) -> None:
    plan = SlicePlan.from_file(two_bodies(tmp_path / "pair.stl"), SliceSettings())
    schedule = LayerSchedule(plan, SliceSettings())
    schedule.made_ahead(0, plan.layer_code(0))  # as the whole-model pass made it ahead
    schedule.cancel_body(1, 4)
    views = [layer_view(schedule, index) for index in range(schedule.layer_count)]
    assert [v["layer"] for v in views] == list(range(schedule.layer_count))
    # nothing of the print's: the code made ahead is still there, no estimate was recorded
    assert list(schedule._ahead) == [0]
    assert schedule.estimates == {}
    assert schedule.lines == {}
    assert schedule.layer_preview(0) == schedule.layer_gcode(0)
    assert list(schedule._ahead) == []  # the printer's slicing took it
    assert set(schedule.estimates) == {0}


def test_held_layers_are_served_without_slicing_and_the_lookahead_stays(tmp_path) -> None:
    plan = SlicePlan.from_file(two_bodies(tmp_path / "pair.stl"), SliceSettings())
    depth = 3

    def print_layers(views: bool) -> list[list[str]]:
        schedule = LayerSchedule(plan, SliceSettings())
        schedule.cancel_body(0, 5)

        async def run() -> list[list[str]]:
            with concurrent.futures.ThreadPoolExecutor(2) as executor:
                source = SlicedSource(schedule, 0, depth, executor, resume=False)
                taken = []
                try:
                    for index in range(schedule.layer_count):
                        taken.append(await source.layer(index))
                        if views and index in (0, 4):
                            await look(schedule, source, index)
                finally:
                    source.close()
                return taken

        return asyncio.run(run())

    async def look(schedule: LayerSchedule, source: SlicedSource, index: int) -> None:
        source.started()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 60
        while source.ready_ahead < depth:  # every layer of the window made
            assert loop.time() < deadline
            await asyncio.sleep(0.01)
        before = (source.ready_ahead, source.next_unsliced, dict(schedule.estimates),
                  dict(schedule.lines))
        assert source.held(index) is not None  # the layer printing, as streamed
        for ahead in range(index + 1, index + 1 + depth):
            held = source.held(ahead)
            assert held is not None
            assert layer_view(schedule, ahead, lines=held) == layer_view(schedule, ahead)
        for other in range(schedule.layer_count):
            layer_view(schedule, other, lines=source.held(other))
        after = (source.ready_ahead, source.next_unsliced, dict(schedule.estimates),
                 dict(schedule.lines))
        assert after == before

    assert print_layers(views=True) == print_layers(views=False)
