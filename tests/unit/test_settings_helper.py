"""The one settings helper (``slicer.options``): typed fields, KEY=VALUE parsing, one error
that the configuration, the slicing settings and the printer link all raise."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.link.config import LinkSettingError, StreamerConfig
from hostd.config import ConfigError, config_from_mapping
from slicer.options import (
    Choice,
    Flag,
    Number,
    SettingError,
    Table,
    Text,
    Texts,
    Whole,
    parse_assignment,
    toml_value,
)
from slicer.settings import SettingsError, SliceSettings


def test_the_three_old_names_are_the_one_class() -> None:
    assert ConfigError is SettingError
    assert SettingsError is SettingError
    assert LinkSettingError is SettingError


@pytest.mark.parametrize(("make", "key"), [
    (lambda: config_from_mapping({"mqtt": {"port": 0}}, Path.cwd()), "mqtt.port"),
    (lambda: SliceSettings.from_mapping({"infill.density": 2}), "infill.density"),
    (lambda: StreamerConfig.from_mapping({"bufsize": "x"}), "bufsize"),
    (lambda: StreamerConfig(history=10), "history"),
    (lambda: config_from_mapping({"slicing": {"perimeters": -1}}, Path.cwd()),
     "slicing.perimeters"),
    (lambda: config_from_mapping({"printer": {"link": {"rx_buffer": 1}}}, Path.cwd()),
     "printer.link.rx_buffer"),
])
def test_the_configuration_the_slicer_and_the_link_raise_the_one_error(make, key) -> None:
    with pytest.raises(SettingError) as caught:
        make()
    assert type(caught.value) is SettingError
    assert caught.value.key == key
    assert str(caught.value) == f"{key}: {caught.value.reason}"


def test_numbers_are_finite_within_their_bounds_and_floats() -> None:
    field = Number(0.0, 1.0)
    assert field.check("k", 1) == 1.0
    assert isinstance(field.check("k", 1), float)
    for bad, reason in ((True, "k: expected a number, got True"),
                        ("0.5", "k: expected a number, got '0.5'"),
                        (float("nan"), "k: must be finite"), (1.5, "k: 1.5 is outside 0..1"),
                        (-0.1, "k: -0.1 is outside 0..1")):
        with pytest.raises(SettingError) as caught:
            field.check("k", bad)
        assert str(caught.value) == reason
    with pytest.raises(SettingError, match="below the minimum 2"):
        Number(low=2.0).check("k", 1)
    with pytest.raises(SettingError, match="above the maximum 2"):
        Number(high=2.0).check("k", 3)
    assert Number().check("k", -1e300) == -1e300


def test_whole_numbers_refuse_fractions_and_take_whole_floats_only_when_asked() -> None:
    assert Whole(1, 10).check("k", 3) == 3
    with pytest.raises(SettingError, match=r"expected a whole number, got 3\.0"):
        Whole(1, 10).check("k", 3.0)
    assert Whole(1, 10, whole_floats=True).check("k", 3.0) == 3
    with pytest.raises(SettingError, match=r"expected a whole number, got 3\.5"):
        Whole(1, 10, whole_floats=True).check("k", 3.5)
    with pytest.raises(SettingError, match="expected a whole number, got inf"):
        Whole(whole_floats=True).check("k", float("inf"))
    with pytest.raises(SettingError, match="expected a whole number, got False"):
        Whole().check("k", False)
    with pytest.raises(SettingError, match=r"^k: 2147483648 is outside 0\.\.2147483647$"):
        Whole(0, 2**31 - 1).check("k", 2**31)


def test_flags_text_choices_and_lists() -> None:
    assert Flag().check("k", False) is False
    with pytest.raises(SettingError, match="expected true or false, got 1"):
        Flag().check("k", 1)
    assert Text().check("k", "") == ""
    with pytest.raises(SettingError, match="must not be empty"):
        Text(empty=False).check("k", "  ")
    with pytest.raises(SettingError, match="'plaid' is not one of linear, wave"):
        Choice(("linear", "wave")).check("k", "plaid")
    assert Texts().check("k", ["a", "b"]) == ("a", "b")
    with pytest.raises(SettingError, match="expected a list of G-code lines, got 'G91'"):
        Texts("G-code lines").check("k", "G91")
    with pytest.raises(SettingError, match="an entry is empty"):
        Texts(empty_items=False).check("k", ["a", " "])
    with pytest.raises(SettingError, match="'x' is not one of done, failed"):
        Texts(choices=("done", "failed")).check("k", ["done", "x"])


def test_command_line_strings_are_read_as_toml_values() -> None:
    assert toml_value(" 0.3 ") == 0.3
    assert toml_value("true") is True
    assert toml_value('"a b"') == "a b"
    assert toml_value("wave") == "wave"
    assert parse_assignment("infill.density = 0.3") == ("infill.density", 0.3)
    assert parse_assignment("infill.field=wave") == ("infill.field", "wave")
    with pytest.raises(SettingError, match=r"^density: expected KEY=VALUE$"):
        parse_assignment("density")
    assert Number(0, 1).parse("k", "0.25") == 0.25
    assert Whole(0, 9).parse("k", "7") == 7
    assert Flag().parse("k", "false") is False
    assert Text().parse("k", "12") == "12"  # a string field keeps the text as given
    with pytest.raises(SettingError, match="expected a number, got 'fast'"):
        Number().parse("k", "fast")


def test_a_table_names_its_keys_and_refuses_those_nothing_read() -> None:
    table = Table({"port": 70000, "hots": "x"}, "mqtt")
    with pytest.raises(SettingError) as caught:
        table.get("port", Whole(1, 65535), 1883)
    assert caught.value.key == "mqtt.port"
    assert table.get("host", Text(), "127.0.0.1") == "127.0.0.1"
    with pytest.raises(SettingError, match=r"^mqtt\.hots: unknown key$"):
        table.refuse_unknown()


def test_an_error_moves_into_its_table() -> None:
    error = SettingError("bufsize", "must be 1..1024 commands")
    assert str(error.within("printer.link")) == "printer.link.bufsize: must be 1..1024 commands"
    assert str(SettingError("", "cannot read x.toml")) == "cannot read x.toml"
    assert error.within("").key == "bufsize"


@settings(max_examples=60, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True) | st.integers() | st.booleans()
       | st.text(max_size=5))
def test_a_number_field_either_returns_a_value_within_bounds_or_refuses(value) -> None:
    field = Number(-10.0, 10.0)
    try:
        checked = field.check("k", value)
    except SettingError as exc:
        key = exc.key
    else:
        key = ""
        assert isinstance(checked, float)
        assert -10.0 <= checked <= 10.0
        assert not isinstance(value, bool | str)
    # refused exactly when the value is not a finite number within the bounds
    within = (not isinstance(value, bool | str) and value == value
              and -10.0 <= value <= 10.0)
    assert key == ("" if within else "k")
