"""The project's one settings helper: typed fields, TOML and ``KEY=VALUE`` parsing, one error.

The daemon's configuration (``hostd.config``), the slicing settings
(``slicer.settings``) and the printer link's settings (``drivers.link.config``)
all check their keys with these fields and raise :class:`SettingError`, whose
message names the key. The module imports nothing of the project (and only the
standard library), so that ``drivers`` may import it although it imports
nothing else of ``slicer``.

- Fields: :class:`Number` (a float within bounds), :class:`Whole` (an int within
  bounds), :class:`Flag` (a bool), :class:`Text` (a string), :class:`Choice` (one
  string of a fixed set) and :class:`Texts` (a list of strings, as a tuple).
  ``field.check(key, value)`` checks a value parsed from TOML and returns it typed;
  ``field.parse(key, text)`` does the same for a command-line string.
- :func:`toml_value` and :func:`parse_assignment` read ``--set KEY=VALUE``.
- :class:`Table`: one TOML table read key by key; ``refuse_unknown()`` names a key
  that nothing read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class SettingError(ValueError):
    """A setting is unknown or its value is wrong: ``key`` names it, ``reason`` says why.

    ``str(error)`` is ``"key: reason"`` (the reason alone when there is no key, as
    for a file that cannot be read).
    """

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"{key}: {reason}" if key else reason)
        self.key = key
        self.reason = reason

    def within(self, prefix: str) -> SettingError:
        """The same error with its key inside the table ``prefix`` (``prefix.key``)."""
        if not prefix:
            return SettingError(self.key, self.reason)
        return SettingError(f"{prefix}.{self.key}" if self.key else prefix, self.reason)


class Field(Generic[T]):
    """A typed setting: checks a value and returns it in its Python type."""

    def check(self, key: str, value: object) -> T:
        """``value`` (as TOML parses it) checked; raises :class:`SettingError` naming ``key``."""
        raise NotImplementedError

    def parse(self, key: str, text: str) -> T:
        """A command-line string read as a TOML value (else as a bare string), then checked."""
        return self.check(key, toml_value(text))


def _bounds(key: str, value: float, low: float | None, high: float | None, shown: str) -> None:
    """Raise unless ``low <= value <= high`` (``None``: unbounded on that side)."""
    def form(bound: float) -> str:
        return f"{bound:g}" if isinstance(bound, float) else str(bound)

    if (low is None or value >= low) and (high is None or value <= high):
        return
    if low is not None and high is not None:
        raise SettingError(key, f"{shown} is outside {form(low)}..{form(high)}")
    if low is not None:
        raise SettingError(key, f"{shown} is below the minimum {form(low)}")
    raise SettingError(key, f"{shown} is above the maximum {form(high)}")  # type: ignore[arg-type]


@dataclass(frozen=True)
class Number(Field[float]):
    """A finite number (int or float) within ``low..high``; returned as a float."""

    low: float | None = None
    high: float | None = None

    def check(self, key: str, value: object) -> float:
        """The number as a float; refuses booleans, strings, NaN, infinities, out of range."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SettingError(key, f"expected a number, got {value!r}")
        if not math.isfinite(value):
            raise SettingError(key, "must be finite")
        _bounds(key, value, self.low, self.high, repr(value))
        return float(value)


@dataclass(frozen=True)
class Whole(Field[int]):
    """A whole number within ``low..high``; ``whole_floats`` also takes ``3.0`` as 3."""

    low: int | None = None
    high: int | None = None
    whole_floats: bool = False

    def check(self, key: str, value: object) -> int:
        """The number as an int; refuses booleans, fractions (and floats unless allowed)."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SettingError(key, f"expected a whole number, got {value!r}")
        if isinstance(value, float) and not (
            self.whole_floats and math.isfinite(value) and value.is_integer()
        ):
            raise SettingError(key, f"expected a whole number, got {value!r}")
        _bounds(key, int(value), self.low, self.high, repr(value))
        return int(value)


@dataclass(frozen=True)
class Flag(Field[bool]):
    """``true`` or ``false``."""

    def check(self, key: str, value: object) -> bool:
        """The boolean; refuses anything else (``1``, ``"yes"``)."""
        if not isinstance(value, bool):
            raise SettingError(key, f"expected true or false, got {value!r}")
        return value


@dataclass(frozen=True)
class Text(Field[str]):
    """A string; ``empty=False`` refuses one that is empty or blank."""

    empty: bool = True

    def check(self, key: str, value: object) -> str:
        """The string."""
        if not isinstance(value, str):
            raise SettingError(key, f"expected a string, got {value!r}")
        if not self.empty and not value.strip():
            raise SettingError(key, "must not be empty")
        return value

    def parse(self, key: str, text: str) -> str:
        """A quoted TOML string unquoted, else the text as it is."""
        value = toml_value(text)
        return self.check(key, value if isinstance(value, str) else text.strip())


@dataclass(frozen=True)
class Choice(Field[str]):
    """One string of ``choices``."""

    choices: tuple[str, ...]

    def check(self, key: str, value: object) -> str:
        """The string, if it is one of the choices."""
        if not isinstance(value, str):
            raise SettingError(key, f"expected a string, got {value!r}")
        if value not in self.choices:
            raise SettingError(key, f"{value!r} is not one of {', '.join(self.choices)}")
        return value


@dataclass(frozen=True)
class Texts(Field[tuple[str, ...]]):
    """A list of strings (``what`` names them in the message), returned as a tuple.

    ``empty_items=False`` refuses a blank entry; ``choices`` limits the entries.
    """

    what: str = "strings"
    empty_items: bool = True
    choices: tuple[str, ...] | None = None

    def check(self, key: str, value: object) -> tuple[str, ...]:
        """The strings as a tuple."""
        if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
            raise SettingError(key, f"expected a list of {self.what}, got {value!r}")
        items: tuple[str, ...] = tuple(value)
        for item in items:
            if not self.empty_items and not item.strip():
                raise SettingError(key, "an entry is empty")
            if self.choices is not None and item not in self.choices:
                raise SettingError(key, f"{item!r} is not one of {', '.join(self.choices)}")
        return items


def toml_value(text: str) -> Any:
    """``text`` read as a TOML value (``0.3``, ``true``, ``"a b"``, ``[1, 2]``), else the
    stripped text itself (``wave``)."""
    import tomllib  # only the commands that are given a string pay for it

    raw = text.strip()
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw


def parse_assignment(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` from the command line as the key and a TOML-typed value."""
    if "=" not in text:
        raise SettingError(text, "expected KEY=VALUE")
    key, _, raw = text.partition("=")
    return key.strip(), toml_value(raw)


class Table:
    """One TOML table being read: typed getters that remember which keys were read.

    Errors name ``name.key``; :meth:`refuse_unknown` refuses the keys nothing read.
    """

    def __init__(self, values: Mapping[str, Any], name: str) -> None:
        self.values = values
        self.name = name
        self.used: set[str] = set()

    def key(self, key: str) -> str:
        """The dotted name of ``key`` in this table."""
        return f"{self.name}.{key}" if self.name else key

    def raw(self, key: str, default: Any) -> Any:
        """The value of ``key`` as given (``default`` when absent), unchecked."""
        self.used.add(key)
        return self.values.get(key, default)

    def get(self, key: str, field: Field[T], default: Any) -> T:
        """The value of ``key`` (``default`` when absent) checked by ``field``."""
        return field.check(self.key(key), self.raw(key, default))

    def fail(self, key: str, reason: str) -> SettingError:
        """The error for ``key`` of this table (to raise)."""
        return SettingError(self.key(key), reason)

    def refuse_unknown(self) -> None:
        """Raise for the first key that no getter read."""
        for key in self.values:
            if key not in self.used:
                raise self.fail(key, "unknown key")


__all__ = [
    "Choice",
    "Field",
    "Flag",
    "Number",
    "SettingError",
    "Table",
    "Text",
    "Texts",
    "Whole",
    "parse_assignment",
    "toml_value",
]
