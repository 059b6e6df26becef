"""The commands' arguments as typed dataclasses, read and checked in one place.

The control socket and MQTT hand the controller each command's arguments as a
JSON object; :func:`read_args` turns them into the command's dataclass, each key
checked by a field of the project's settings helper (:mod:`slicer.options`), so
a wrong argument raises the one :class:`~slicer.options.SettingError` naming the
key, which the controller refuses as ``CMD needs "KEY": REASON``. Keys a command
does not read are ignored, as before.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from slicer.options import Field, Number, SettingError, Text, Whole

T = TypeVar("T")

_MISSING = object()
_JOB = Text(empty=False)


@dataclass(frozen=True)
class Pair(Field[tuple[int, int]]):
    """Two whole numbers ``[a, b]``, each within ``low..high`` (``what`` names them)."""

    what: str
    low: int
    high: int

    def check(self, key: str, value: object) -> tuple[int, int]:
        """The pair as a tuple; refuses anything but a list of two numbers in range."""
        if not (isinstance(value, list | tuple) and len(value) == 2 and all(
                isinstance(v, int) and not isinstance(v, bool) and self.low <= v <= self.high
                for v in value)):
            raise SettingError(key, f"must be [{self.what}], each {self.low}..{self.high}")
        return int(value[0]), int(value[1])


@dataclass(frozen=True)
class Changes(Field[dict[str, Any]]):
    """A non-empty object of flat slicing keys and their values (checked by the schedule)."""

    def check(self, key: str, value: object) -> dict[str, Any]:
        """The changes as a dict; refuses anything but a non-empty object of string keys."""
        if not isinstance(value, dict) or not value or not all(isinstance(k, str) for k in value):
            raise SettingError(key, "{KEY: VALUE, ...} (flat slicing keys)")
        return dict(value)


class _Reader:
    """One command's arguments being read: a key's value checked by a field."""

    def __init__(self, args: Mapping[str, Any]) -> None:
        self.args = args

    def get(self, key: str, field: Field[T], what: str, default: Any = _MISSING,
            alias: str | None = None, null: bool = False) -> T:
        """``key`` (or ``alias``) checked by ``field``; ``default`` when absent (or JSON
        ``null``, when ``null``), else refused with ``what`` (what the key should be)."""
        value = self.args.get(key, self.args.get(alias, _MISSING) if alias else _MISSING)
        if value is _MISSING or (null and value is None):
            if default is _MISSING:
                raise SettingError(key, what)
            return default  # type: ignore[no-any-return]
        return field.check(key, value)

    def job(self) -> str:
        """The ``job`` key: a job's id or name (a number is taken as an id)."""
        value = self.args.get("job")
        if isinstance(value, int) and not isinstance(value, bool):
            value = str(value)
        if value is None:
            raise SettingError("job", "a job's id or name")
        return _JOB.check("job", value)


@dataclass(frozen=True)
class JobArgs:
    """``resume_job``, ``queue_remove``: ``{"job": ID or NAME}``."""

    job: str

    @classmethod
    def read(cls, args: Mapping[str, Any]) -> JobArgs:
        return cls(_Reader(args).job())


@dataclass(frozen=True)
class QueueMoveArgs:
    """``queue_move``: ``{"job": ID, "index": N}`` (0 = next)."""

    job: str
    index: int

    @classmethod
    def read(cls, args: Mapping[str, Any]) -> QueueMoveArgs:
        reader = _Reader(args)
        job = reader.job()
        return cls(job, reader.get("index", Whole(0, None), "a queue position, 0 or more"))


@dataclass(frozen=True)
class ObjectArgs:
    """``cancel_object``, ``restore_object``: ``{"object": N}`` (also ``"body"``)."""

    object: int

    @classmethod
    def read(cls, args: Mapping[str, Any]) -> ObjectArgs:
        return cls(_Reader(args).get("object", Whole(0, None), "a body number from 0",
                                     alias="body"))


@dataclass(frozen=True)
class RetuneArgs:
    """``set``: ``{"settings": {KEY: VALUE, ...}}`` or ``{"key": KEY, "value": VALUE}``."""

    settings: dict[str, Any]

    @classmethod
    def read(cls, args: Mapping[str, Any]) -> RetuneArgs:
        reader = _Reader(args)
        if "settings" in args:
            return cls(reader.get("settings", Changes(), ""))
        if "key" in args and "value" in args:
            return cls({reader.get("key", Text(empty=False), ""): args["value"]})
        raise SettingError("settings", '{KEY: VALUE, ...}, or "key" and "value"')


@dataclass(frozen=True)
class LayerArgs:
    """``layer``: ``{"layer": N, "tolerance": MM, "field": [COLUMNS, ROWS]}``, each optional
    (the layer printing, 0.2 mm, no field)."""

    layer: int | None = None
    tolerance: float = 0.2
    field: tuple[int, int] | None = None

    @classmethod
    def read(cls, args: Mapping[str, Any]) -> LayerArgs:
        reader = _Reader(args)
        return cls(
            reader.get("layer", Whole(None, None), "", default=None),
            reader.get("tolerance", Number(0.0, 50.0), "", default=0.2),
            reader.get("field", Pair("columns, rows", 1, 1000), "", default=None, null=True),
        )


@dataclass(frozen=True)
class EstimateArgs:
    """``estimate``: ``{"settings": {KEY: VALUE, ...}}`` (optional: the job as it is)."""

    settings: dict[str, Any] | None = None

    @classmethod
    def read(cls, args: Mapping[str, Any]) -> EstimateArgs:
        return cls(_Reader(args).get("settings", Changes(), "", default=None, null=True))


def read_args(command: str, reader: Callable[[Mapping[str, Any]], T],
              args: Mapping[str, Any]) -> T:
    """``reader(args)`` (one of the ``read`` class methods above); a wrong argument
    raises :class:`ArgumentError` with ``CMD needs "KEY": REASON``."""
    try:
        return reader(args)
    except SettingError as exc:
        raise ArgumentError(command, exc) from exc


class ArgumentError(ValueError):
    """A command's argument is missing or wrong (``error``: which key and why)."""

    def __init__(self, command: str, error: SettingError) -> None:
        super().__init__(f'{command} needs "{error.key}": {error.reason}')
        self.command = command
        self.error = error
