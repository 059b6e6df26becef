"""One-shot `hostd` commands keep numpy's BLAS on one thread (its start-up spins no
core); the daemon and `hostd tailor`, whose finite-element solves gain from a pool,
keep it."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

# runs a command (bad input: it stops after importing its module, numpy included), then
# counts this process's threads
_THREADS_AFTER = (
    "import os, sys, contextlib, io\n"
    "from hostd.app import cli\n"
    "with contextlib.redirect_stderr(io.StringIO()):\n"
    "    cli.main(sys.argv[1:])\n"
    "assert 'numpy' in sys.modules\n"
    "print(len(os.listdir('/proc/self/task')), os.environ.get('OPENBLAS_NUM_THREADS', '-'))\n"
)


def _threads(*command: str, env: dict[str, str] | None = None) -> list[str]:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", _THREADS_AFTER, *command],
                         env=clean | (env or {}), capture_output=True, text=True, check=True,
                         timeout=120)
    return out.stdout.split()


def _two_cores() -> None:
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: OpenBLAS starts no pool whatever is asked")


def test_a_slice_loads_numpy_with_one_thread(tmp_path) -> None:
    assert _threads("slice", str(tmp_path / "missing.stl"), "-o", str(tmp_path / "x.gcode")) \
        == ["1", "1"]


def test_tailor_keeps_the_pool(tmp_path) -> None:
    _two_cores()
    threads, asked = _threads("tailor", str(tmp_path / "missing.stl"))
    assert asked == "-"
    assert int(threads) >= 2


def test_the_environment_still_decides(tmp_path) -> None:
    _two_cores()
    threads, asked = _threads("slice", str(tmp_path / "missing.stl"), "-o",
                              str(tmp_path / "x.gcode"), env={"OPENBLAS_NUM_THREADS": "2"})
    assert asked == "2"
    assert int(threads) >= 2
