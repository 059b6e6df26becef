"""The test layers keep their rules, where reading the code can tell.

tests/unit is pure (no pty, no subprocess, no broker, no daemon, no SQLite),
tests/integration may use a pty, SQLite, a broker or threads but starts no daemon
process, tests/e2e runs the daemon or the `hostd` command as a process. The code
the layers share is the ``support`` package; no test module imports another.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]
LAYERS = ("unit", "integration", "e2e")
SUPPORT = TESTS / "support"
# what a unit test may not import, itself or through the support code it imports
NOT_IN_UNIT = {"subprocess", "pty", "sqlite3", "support.brokers", "support.daemon_helpers",
               "support.daemon_process"}
# what starts the daemon or the `hostd` command as a process: the end-to-end layer's
NOT_IN_INTEGRATION = {"support.daemon_process.DaemonProcess", "support.paths.HOSTD"}


def modules_of(layer: str | None = None) -> list[Path]:
    """Every test module under tests/, or those of one layer."""
    root = TESTS / layer if layer else TESTS
    return sorted(root.rglob("test_*.py"))


@cache
def imports_of(path: Path) -> frozenset[str]:
    """The modules ``path`` imports anywhere in its code, and ``module.name`` for each
    name taken from a module (``from a import b`` gives ``a`` and ``a.b``)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return frozenset(found)


@cache
def reached_from(path: Path) -> frozenset[str]:
    """What ``path`` imports, with what the support modules it imports import in turn."""
    found = set(imports_of(path))
    for name in imports_of(path):
        parts = name.split(".")
        if parts[0] == "support" and len(parts) > 1:
            module = SUPPORT / f"{parts[1]}.py"
            if module.exists() and module != path:
                found |= reached_from(module)
    return frozenset(found)


def forbidden(names: frozenset[str], rules: set[str]) -> list[str]:
    """The names that are, or lie inside, one of ``rules``."""
    return sorted(n for n in names if any(n == r or n.startswith(r + ".") for r in rules))


def test_every_test_module_lives_in_a_layer() -> None:
    outside = [p.relative_to(TESTS).as_posix() for p in modules_of()
               if p.relative_to(TESTS).parts[0] not in LAYERS]
    assert outside == []


def test_no_test_module_imports_another_or_the_conftest() -> None:
    modules = modules_of() + sorted(SUPPORT.glob("*.py"))
    offenders = {
        path.relative_to(TESTS).as_posix(): sorted(
            name for name in imports_of(path)
            if name.split(".")[0] in ("conftest", "tests", "unit", "integration", "e2e")
            or name.split(".")[-1].startswith("test_")
            or (name.count(".") == 0 and name.startswith("test_")))
        for path in modules
    }
    assert {path: names for path, names in offenders.items() if names} == {}


@pytest.mark.parametrize("layer", ["unit", "integration", "e2e"])
def test_the_layer_has_its_modules(layer: str) -> None:
    assert modules_of(layer), f"tests/{layer} holds no test module"


def test_unit_tests_start_no_process_pty_broker_daemon_or_database() -> None:
    offenders = {path.name: forbidden(reached_from(path), NOT_IN_UNIT)
                 for path in modules_of("unit")}
    assert {name: names for name, names in offenders.items() if names} == {}


def test_integration_tests_start_no_daemon_or_hostd_process() -> None:
    offenders = {}
    for path in modules_of("integration"):
        names = forbidden(imports_of(path), NOT_IN_INTEGRATION)
        tree = ast.parse(path.read_text(), str(path))
        names += [f"{node.name}(daemon)" for node in ast.walk(tree)
                  if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
                  and node.name.startswith("test_")
                  and any(arg.arg == "daemon" for arg in node.args.args)]
        if names:
            offenders[path.name] = names
    assert offenders == {}


def test_the_rules_catch_what_they_forbid(tmp_path: Path) -> None:
    # the checks above read the code; one module breaking each rule proves they can fail
    bad = tmp_path / "test_bad.py"
    bad.write_text("import subprocess\nfrom support.brokers import HOST\n"
                   "from test_other import helper\n\ndef test_x(daemon):\n    import pty\n")
    names = reached_from(bad)
    assert forbidden(names, NOT_IN_UNIT) == ["pty", "subprocess", "support.brokers",
                                             "support.brokers.HOST"]
    assert "test_other" in names
