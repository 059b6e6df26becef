"""The import arrows of the design: slicer and drivers stand alone; tui sees only hostd.api."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("hostd", "slicer", "drivers", "tui")


def imported_modules(path: Path) -> set[str]:
    """Every absolute module name a source file imports (top-level or nested)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def project_imports(package: str) -> dict[str, set[str]]:
    """Per source file of ``package``: the project modules it imports."""
    found: dict[str, set[str]] = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        mods = {m for m in imported_modules(path) if m.split(".")[0] in PACKAGES}
        found[str(path.relative_to(ROOT))] = mods
    return found


@pytest.mark.parametrize("package", ["slicer", "drivers"])
def test_libraries_never_import_the_daemon_or_the_dashboard(package: str) -> None:
    offenders = {
        path: sorted(m for m in mods if m.split(".")[0] in ("hostd", "tui"))
        for path, mods in project_imports(package).items()
    }
    offenders = {path: mods for path, mods in offenders.items() if mods}
    assert offenders == {}


# the one settings helper: the only module of the slicer the link may import
SETTINGS_HELPER = "slicer.options"


def test_slicer_and_drivers_do_not_import_each_other() -> None:
    crossing = {
        path: sorted(m for m in mods if m.split(".")[0] == other
                     and not (other == "slicer" and (m == SETTINGS_HELPER
                                                     or m.startswith(SETTINGS_HELPER + "."))))
        for package, other in (("slicer", "drivers"), ("drivers", "slicer"))
        for path, mods in project_imports(package).items()
    }
    assert {path: mods for path, mods in crossing.items() if mods} == {}


def test_the_settings_helper_imports_nothing_of_the_project() -> None:
    path = ROOT / (SETTINGS_HELPER.replace(".", "/") + ".py")
    assert {m for m in imported_modules(path) if m.split(".")[0] in PACKAGES} == set()


def test_dashboard_talks_only_through_the_control_api() -> None:
    allowed = {"hostd", "hostd.api"}
    offenders = {}
    for path, mods in project_imports("tui").items():
        bad = sorted(
            m for m in mods
            if m.split(".")[0] in ("slicer", "drivers")
            or (m.split(".")[0] == "hostd" and not any(m == a or m.startswith("hostd.api.")
                                                       for a in allowed))
        )
        if bad:
            offenders[path] = bad
    assert offenders == {}


@pytest.mark.parametrize(
    ("module", "forbidden"),
    [
        ("slicer.plan", ("hostd", "tui", "drivers")),
        ("drivers.link.streamer", ("hostd", "tui", "slicer")),
        ("drivers.sim.printer", ("hostd", "tui", "slicer")),
    ],
)
def test_importing_a_library_loads_nothing_above_it(
    module: str, forbidden: tuple[str, ...]
) -> None:
    # the link loads the settings helper (and its package's empty __init__), no more
    allowed = ("slicer", SETTINGS_HELPER)
    code = (
        "import importlib, sys\n"
        f"importlib.import_module({module!r})\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {forbidden!r}\n"
        f"             and m not in {allowed!r})\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == ""
