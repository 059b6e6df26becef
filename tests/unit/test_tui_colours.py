"""The layer picture's colours in true colour, 256 and 16 colours: every type keeps its own."""

from __future__ import annotations

import asyncio
import itertools
import re

import pytest
import textual.constants
from rich.color import Color, ColorSystem
from support.tui_helpers import FixedSource
from support.waiting import until

from tui.app import Dashboard
from tui.widgets.layer import CANCELLED, HIGHLIGHT, KINDS, OTHER, LayerView

SYSTEMS = (ColorSystem.TRUECOLOR, ColorSystem.EIGHT_BIT, ColorSystem.STANDARD)


def picture_colours() -> dict[str, str]:
    """Every colour the picture draws paths and outlines in, by what it means."""
    colours = {f"{kind} {stage}": colour for kind, pair in {**KINDS, "other": OTHER}.items()
               for stage, colour in zip(("printed", "to come"), pair, strict=True)}
    return {**colours, "highlighted body": HIGHLIGHT, "cancelled body": CANCELLED}


def downgraded(colour: str, system: ColorSystem) -> object:
    """The colour a terminal of ``system`` shows (what rich writes for Textual)."""
    down = Color.parse(colour).downgrade(system)
    return down.triplet if system == ColorSystem.TRUECOLOR else down.number


@pytest.mark.parametrize("system", SYSTEMS, ids=lambda s: s.name.lower())
def test_every_type_printed_or_to_come_keeps_its_own_colour(system: ColorSystem) -> None:
    shown = {meaning: downgraded(colour, system) for meaning, colour in picture_colours().items()}
    for (a, colour_a), (b, colour_b) in itertools.combinations(shown.items(), 2):
        assert colour_a != colour_b, f"{a} and {b} both show as {colour_a} in {system.name}"


def test_printed_is_brighter_than_to_come_in_16_colours() -> None:
    for kind, (printed, to_come) in {**KINDS, "other": OTHER}.items():
        bright = downgraded(printed, ColorSystem.STANDARD)
        normal = downgraded(to_come, ColorSystem.STANDARD)
        assert isinstance(bright, int)
        assert isinstance(normal, int)
        assert bright >= 7, kind  # a bright ANSI colour (or white)
        assert normal <= 8, kind  # a normal one (or bright black)
        assert bright != normal, kind


def sgr_colour(colour: str) -> str:
    """The SGR foreground code of a colour in 16 colours (31, 91...)."""
    number = Color.parse(colour).downgrade(ColorSystem.STANDARD).number
    assert number is not None
    return str(30 + number if number < 8 else 90 + number - 8)


def test_the_dashboard_renders_in_16_colours(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(textual.constants, "COLOR_SYSTEM", "standard")

    async def scenario() -> tuple[str, list[set[str]]]:
        app = Dashboard(FixedSource())
        async with app.run_test(size=(80, 24)) as pilot:
            screen = app.printer_screen
            view = screen.query_one(LayerView)
            await until(lambda: screen.layer_data is not None and view.printed is not None)
            await pilot.pause()
            assert app.console.color_system == "standard"
            assert 0 < view.printed_paths() < len(screen.layer_data["paths"])
            paths, done = screen.layer_data["paths"], view.printed_paths()
            kinds = [{path["kind"] for path in part} for part in (paths[:done], paths[done:])]
            # what Textual writes to a 16-colour terminal, for the whole screen
            update = screen._compositor.render_update(full=True)
            return update.render_segments(app.console), kinds

    output, kinds = asyncio.run(scenario())
    codes = {code for sgr in re.findall(r"\x1b\[([0-9;]*)m", output) for code in sgr.split(";")}
    assert "38" not in codes
    assert "48" not in codes
    assert kinds[0]
    assert kinds[1]
    for stage, drawn in enumerate(kinds):
        for kind in drawn:
            assert sgr_colour(KINDS[kind][stage]) in codes, (kind, stage)

