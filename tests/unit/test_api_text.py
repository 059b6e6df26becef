"""The one duration formatter and the one progress bar the daemon, its commands and the
dashboards print."""

from __future__ import annotations

import pytest

from hostd.api import bar, duration


def test_a_clock_shows_hours_only_when_there_are_some() -> None:
    assert duration(0) == "0:00"
    assert duration(59.9) == "0:59"  # whole seconds passed, not rounded up
    assert duration(103) == "1:43"
    assert duration(3599) == "59:59"
    assert duration(3600) == "1:00:00"
    assert duration(3725) == "1:02:05"
    assert duration(36000 + 61) == "10:01:01"


def test_a_column_of_clocks_always_has_hours() -> None:
    assert duration(103, hours=True) == "0:01:43"
    assert duration(3700, hours=True) == "1:01:40"
    assert duration(90061, hours=True) == "25:01:01"


def test_words_round_to_the_nearest_second() -> None:
    assert duration(62.4, words=True) == "1m 02s"
    assert duration(59.6, words=True) == "1m 00s"
    assert duration(3723, words=True) == "1h 02m 03s"


def test_unknown_and_negative_spans() -> None:
    assert duration(None) == "--"
    assert duration(None, hours=True, unknown="unknown") == "unknown"
    assert duration(-5) == "0:00"
    assert duration(-5, words=True) == "0m 00s"


def test_a_bar_in_eighths_of_a_cell() -> None:
    assert bar(0.0, 4) == "····"
    assert bar(0.55, 8) == "████▍···"  # 35.2 eighths: 4 cells and 3 eighths
    assert bar(1.0, 4) == "████"
    assert bar(1.7, 4) == "████"
    assert bar(-1.0, 3, empty=" ") == "   "
    assert bar(0.5, -2) == ""


def test_an_ascii_bar_in_whole_cells() -> None:
    assert bar(0.0, 5, ascii=True) == "-----"
    assert bar(0.5, 10, ascii=True) == "#####-----"
    assert bar(0.04, 10, ascii=True) == "----------"
    assert bar(1.0, 3, ascii=True) == "###"


@pytest.mark.parametrize("width", [1, 7, 8, 17, 30])
def test_a_bar_is_always_its_width_and_grows_with_the_fraction(width: int) -> None:
    for ascii in (False, True):
        drawn = [bar(k / 97, width, ascii=ascii) for k in range(98)]
        assert {len(text) for text in drawn} == {width}
        filled = [sum(c not in "·-" for c in text) for text in drawn]
        assert filled == sorted(filled)
        assert drawn[-1] == ("#" if ascii else "█") * width
