"""Shared fixtures, and the test layers: tests/unit, tests/integration, tests/e2e.

Each test is marked with the name of its module's folder, so ``-m unit`` and
``tests/unit`` select the same tests; the layers run in that order. The code
they share is the ``support`` package beside this file (``from support.X import``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import settings as hypothesis_settings
from support.daemon_process import DaemonProcess, sim_config

# `pytest --hypothesis-profile long`: the benchmark's run of the property suites
hypothesis_settings.register_profile("long", max_examples=500, deadline=None)

LAYERS = ("unit", "integration", "e2e")
TESTS = Path(__file__).resolve().parent


def layer_of(item: pytest.Item) -> str | None:
    """The layer (a folder of ``LAYERS``) a test's module lives in, if any."""
    path = item.path.resolve()
    parts = path.relative_to(TESTS).parts if path.is_relative_to(TESTS) else ()
    return parts[0] if len(parts) > 1 and parts[0] in LAYERS else None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark each test with its layer, and run the layers in order: unit first, e2e last."""
    for item in items:
        layer = layer_of(item)
        if layer is not None:
            item.add_marker(layer)
    rank = {layer: n for n, layer in enumerate(LAYERS)}
    items.sort(key=lambda item: rank.get(layer_of(item) or "", len(LAYERS)))


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[Callable[..., DaemonProcess]]:
    """A factory: ``daemon(config_text)`` starts `hostd run` in ``tmp_path``."""
    started: list[DaemonProcess] = []

    def start(config_text: str | None = None) -> DaemonProcess:
        process = DaemonProcess(tmp_path, config_text or sim_config())
        started.append(process)
        return process.start()

    yield start
    for process in started:
        process.close()
