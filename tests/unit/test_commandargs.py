"""The commands' arguments read into typed dataclasses, each wrong one refused naming its key."""

from __future__ import annotations

from typing import Any

import pytest

from hostd.printing.commandargs import (
    ArgumentError,
    EstimateArgs,
    JobArgs,
    LayerArgs,
    ObjectArgs,
    QueueMoveArgs,
    RetuneArgs,
    read_args,
)

pytestmark = pytest.mark.unit


def test_arguments_are_read_typed_with_their_defaults_and_aliases() -> None:
    assert read_args("cancel_object", ObjectArgs.read, {"object": 1}) == ObjectArgs(1)
    assert read_args("cancel_object", ObjectArgs.read, {"body": 2}) == ObjectArgs(2)
    assert read_args("resume_job", JobArgs.read, {"job": 7}) == JobArgs("7")
    assert read_args("resume_job", JobArgs.read, {"job": "bunny.stl"}) == JobArgs("bunny.stl")
    assert read_args("queue_move", QueueMoveArgs.read, {"job": "3", "index": 0}) == (
        QueueMoveArgs("3", 0))
    assert read_args("layer", LayerArgs.read, {}) == LayerArgs(None, 0.2, None)
    assert read_args("layer", LayerArgs.read, {"layer": 4, "tolerance": 1, "field": [3, 2]}) == (
        LayerArgs(4, 1.0, (3, 2)))
    # a JSON null is no field, no retune (as the dashboard sends them)
    assert read_args("layer", LayerArgs.read, {"layer": 1, "field": None}) == (
        LayerArgs(1, 0.2, None))
    assert read_args("estimate", EstimateArgs.read, {}) == EstimateArgs(None)
    assert read_args("estimate", EstimateArgs.read, {"settings": None}) == EstimateArgs(None)
    assert read_args("set", RetuneArgs.read, {"settings": {"infill.density": 0.4}}) == (
        RetuneArgs({"infill.density": 0.4}))
    assert read_args("set", RetuneArgs.read, {"key": "fan_speed", "value": 0.5}) == (
        RetuneArgs({"fan_speed": 0.5}))


@pytest.mark.parametrize(("command", "reader", "args", "key"), [
    ("cancel_object", ObjectArgs.read, {}, "object"),
    ("cancel_object", ObjectArgs.read, {"object": True}, "object"),
    ("cancel_object", ObjectArgs.read, {"object": "1"}, "object"),
    ("restore_object", ObjectArgs.read, {"object": -1}, "object"),
    ("restore_object", ObjectArgs.read, {"object": 1.5}, "object"),
    ("resume_job", JobArgs.read, {}, "job"),
    ("resume_job", JobArgs.read, {"job": ""}, "job"),
    ("queue_remove", JobArgs.read, {"job": [1]}, "job"),
    ("queue_move", QueueMoveArgs.read, {"job": "1"}, "index"),
    ("queue_move", QueueMoveArgs.read, {"job": "1", "index": -2}, "index"),
    ("queue_move", QueueMoveArgs.read, {"job": "1", "index": False}, "index"),
    ("layer", LayerArgs.read, {"layer": "2"}, "layer"),
    ("layer", LayerArgs.read, {"layer": None}, "layer"),
    ("layer", LayerArgs.read, {"tolerance": None}, "tolerance"),
    ("layer", LayerArgs.read, {"tolerance": 51}, "tolerance"),
    ("layer", LayerArgs.read, {"tolerance": float("nan")}, "tolerance"),
    ("layer", LayerArgs.read, {"field": [0, 5]}, "field"),
    ("layer", LayerArgs.read, {"field": [5]}, "field"),
    ("layer", LayerArgs.read, {"field": [True, 5]}, "field"),
    ("estimate", EstimateArgs.read, {"settings": {}}, "settings"),
    ("estimate", EstimateArgs.read, {"settings": [1]}, "settings"),
    ("set", RetuneArgs.read, {}, "settings"),
    ("set", RetuneArgs.read, {"key": "fan_speed"}, "settings"),
    ("set", RetuneArgs.read, {"key": "", "value": 1}, "key"),
])
def test_a_wrong_argument_is_refused_naming_the_command_and_its_key(
    command: str, reader: Any, args: dict[str, Any], key: str,
) -> None:
    with pytest.raises(ArgumentError) as raised:
        read_args(command, reader, args)
    assert raised.value.error.key == key
    assert str(raised.value).startswith(f'{command} needs "{key}": ')
