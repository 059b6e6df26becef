"""The one duration formatter: the forms the daemon, its commands and the dashboard print."""

from __future__ import annotations

from hostd.api import duration


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
