"""How the `hostd` console script ends: exit handlers run and output is flushed, the
interpreter is not torn down when nothing else runs, and running threads are waited for."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from support.slicer_helpers import box_stl

_QUICK = """
import atexit, sys
atexit.register(lambda: print("exit handler ran", flush=True))
sys.stdout.write("unflushed line\\n")  # left in the buffer: the exit must flush it
sys.argv = ["hostd", *sys.argv[1:]]
from hostd.app.cli import entry
entry()
"""

_THREAD = """
import sys, threading, time
def late():
    time.sleep(0.3)
    print("thread finished", flush=True)
threading.Thread(target=late).start()
sys.argv = ["hostd", *sys.argv[1:]]
from hostd.app.cli import entry
entry()
"""


def _run(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=120)


def test_a_slice_ends_with_its_exit_handlers_run_and_its_output_flushed(tmp_path: Path) -> None:
    model = box_stl(tmp_path / "box.stl", (10, 10, 2))
    out = tmp_path / "box.gcode"
    done = _run(_QUICK, "slice", str(model), "-o", str(out), "--quiet")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "unflushed line"
    assert lines[1].startswith(f"{out}: 10 layers")
    assert lines[-1] == "exit handler ran"
    assert out.read_text().rstrip().endswith("M84")


def test_bad_input_keeps_its_exit_code_and_message(tmp_path: Path) -> None:
    done = _run(_QUICK, "slice", str(tmp_path / "missing.stl"), "-o", str(tmp_path / "x.gcode"))
    assert done.returncode == 2
    assert "missing.stl: no such file" in done.stderr
    assert done.stdout.splitlines()[-1] == "exit handler ran"


def test_a_thread_still_running_is_waited_for(tmp_path: Path) -> None:
    done = _run(_THREAD, "slice", str(tmp_path / "missing.stl"), "-o", str(tmp_path / "x.gcode"))
    assert done.returncode == 2
    assert done.stdout.splitlines() == ["thread finished"]


def test_a_reader_gone_ends_the_command_quietly(tmp_path: Path) -> None:
    """Output into a pipe nobody reads (``hostd slice ... | head -1`` once head has left)
    ends the command with exit code 1 and no traceback."""
    import os

    model = box_stl(tmp_path / "box.stl", (10, 10, 2))
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hostd", "slice", str(model), "-o", str(tmp_path / "b.gcode"),
             "--quiet"], stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert "BrokenPipe" not in done.stderr
    assert (tmp_path / "b.gcode").stat().st_size > 0  # the file was written all the same
