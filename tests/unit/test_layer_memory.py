"""Memory during a print: what the schedule holds of the model is a window of layers
below the one being sliced, not every layer sliced so far, and the G-code is the same."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from hostd.jobs.schedule import HELD_LAYERS, LayerSchedule
from slicer.paths import islands
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def cone(tmp_path_factory) -> Path:
    """250 layers, each a circle of its own size (no island repeats), cut in blocks of
    16 layers (enough faces cross each layer)."""
    path: Path = tmp_path_factory.mktemp("models") / "cone.stl"
    trimesh.creation.cone(radius=6.0, height=50.0, sections=256).export(path)
    return path


def test_a_print_holds_a_window_of_layers_and_slices_the_same_bytes(cone: Path) -> None:
    settings = SliceSettings()
    plan = SlicePlan.from_file(cone, settings)
    schedule = LayerSchedule(plan, settings)
    count = plan.layer_count
    assert count > 2 * HELD_LAYERS + 32
    islands.forget()
    printed: list[list[str]] = []
    held: list[tuple[int, int, int]] = []  # (outline blocks, skin blocks, islands) per layer
    for layer in range(count):
        printed.append(schedule.layer_gcode(layer))
        held.append((*plan.held_blocks(), len(islands._kept())))
    # blocks of 16 layers: those of the layers held and the one being sliced (and the
    # outlines of the skin's layers above it), whatever the height of the model
    later = held[HELD_LAYERS + 16:]
    assert max(outlines for outlines, _skins, _kept in later) <= HELD_LAYERS // 16 + 3, held
    assert max(skins for _outlines, skins, _kept in later) <= HELD_LAYERS // 16 + 2, held
    # every layer has islands of its own: kept for all, there would be one per layer
    assert max(kept for _outlines, _skins, kept in held) < count // 2, held

    # a view of a layer let go cuts it again: the same lines as printed
    assert schedule.layer_preview(3) == printed[3]
    # and the whole print is what a plan that forgets nothing slices
    fresh = SlicePlan.from_file(cone, settings)
    assert [fresh.layer_code(i, frozenset()).lines for i in range(count)] == printed
    assert plan.warnings == fresh.warnings
