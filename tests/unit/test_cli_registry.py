"""The one command registry: each `hostd/app/commands/*.py` command brings its arguments and its
`run`, registered once in `hostd.app.commands.COMMANDS`; the command line adds no argument
itself."""

from __future__ import annotations

import ast

from support.paths import ROOT

from hostd.app.commands import COMMANDS


def _top_level_functions(module: str) -> set[str]:
    path = ROOT / (module.replace(".", "/") + ".py")
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}


def test_every_registered_command_brings_its_arguments_and_its_run() -> None:
    for name, command in COMMANDS.items():
        assert command.module.startswith("hostd.app.commands."), name
        assert {"add_arguments", "run"} <= _top_level_functions(command.module), name
        assert command.help, name


def test_every_command_module_is_registered_once() -> None:
    registered = [command.module for command in COMMANDS.values()]
    assert len(registered) == len(set(registered))
    runs = {f"hostd.app.commands.{path.stem}" for path in (ROOT / "hostd/app/commands").glob("*.py")
            if "run" in _top_level_functions(f"hostd.app.commands.{path.stem}")}
    assert runs == set(registered)


def test_the_command_line_adds_no_argument_of_a_command() -> None:
    source = (ROOT / "hostd/app/cli.py").read_text(encoding="utf-8")
    assert "add_argument(" not in source
    assert "add_parser(" in source  # one per registered command, from the registry
