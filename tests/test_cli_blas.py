"""The `hostd` command line keeps numpy's BLAS on one thread (its start-up spins no core)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_COUNT_THREADS = (
    "import os, hostd.cli, numpy; "
    "print(len(os.listdir('/proc/self/task')), os.environ['OPENBLAS_NUM_THREADS'])"
)


def _run(env: dict[str, str]) -> list[str]:
    out = subprocess.run([sys.executable, "-c", _COUNT_THREADS], env=env, capture_output=True,
                         text=True, check=True, timeout=60)
    return out.stdout.split()


def _clean_env() -> dict[str, str]:
    env = dict(os.environ)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(name, None)
    return env


def test_numpy_loads_with_one_thread_after_the_cli() -> None:
    assert _run(_clean_env()) == ["1", "1"]


def test_the_environment_still_decides() -> None:
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: OpenBLAS starts no pool whatever is asked")
    env = _clean_env() | {"OPENBLAS_NUM_THREADS": "2"}
    threads, asked = _run(env)
    assert asked == "2"
    assert int(threads) >= 2
