"""A heap probe for the daemon under ``bench/soak.py --heap-probe``: where its RSS is.

Put on ``PYTHONPATH`` with ``HOSTD_HEAPPROBE=FILE`` set, it is imported by every
Python process started so; in ``hostd run`` only, it answers ``SIGUSR2`` by
collecting garbage, trimming the C heap (``malloc_trim``), and appending one JSON
line to ``FILE``: the RSS split into anonymous memory and pages of files, and for
each glibc arena (``malloc_info``) the bytes it has from the system and those of
its free chunks (the rest is in use), and Python's small-object arenas (those in
blocks in use, free blocks, free pools). Python's own allocations, if
``HOSTD_HEAPPROBE_TRACE=N`` started ``tracemalloc`` with N frames, are summed too,
and with ``HOSTD_HEAPPROBE_TOP=K`` the K largest of them are listed with where
they were allocated.
Read only between jobs: the handler runs on the daemon's main thread.
"""

from __future__ import annotations

import ctypes
import gc
import json
import os
import signal
import sys
import xml.etree.ElementTree as ET

_OUT = os.environ.get("HOSTD_HEAPPROBE")


def _status_mb(field: str) -> float:
    with open("/proc/self/status", encoding="ascii") as handle:
        for line in handle:
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _arenas(libc: ctypes.CDLL) -> list[dict[str, float]]:
    """Each glibc arena's bytes from the system and free, in MB (``malloc_info``)."""
    size = ctypes.c_size_t()
    buf = ctypes.c_char_p()
    libc.open_memstream.restype = ctypes.c_void_p
    libc.open_memstream.argtypes = [ctypes.POINTER(ctypes.c_char_p),
                                    ctypes.POINTER(ctypes.c_size_t)]
    libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    libc.fclose.argtypes = [ctypes.c_void_p]
    stream = libc.open_memstream(ctypes.byref(buf), ctypes.byref(size))
    libc.malloc_info(0, stream)
    libc.fclose(stream)
    text = ctypes.string_at(buf, size.value).decode("ascii")
    libc.free(buf)
    arenas = []
    for heap in ET.fromstring(text).findall("heap"):
        system = sum(int(s.get("size", 0)) for s in heap.findall("system")
                     if s.get("type") == "current")
        free = sum(int(t.get("size", 0)) for t in heap.findall("total")
                   if t.get("type") in ("fast", "rest"))
        arenas.append({"system_mb": round(system / 2**20, 2), "free_mb": round(free / 2**20, 2),
                       "in_use_mb": round((system - free) / 2**20, 2)})
    return arenas


def _pymalloc() -> dict[str, float]:
    """Python's small-object allocator (``sys._debugmallocstats``, written by C to
    stderr, read back through a file): its arenas' MB, and of those the MB in blocks
    in use and in free blocks of its pools."""
    import tempfile

    with tempfile.TemporaryFile() as capture:
        sys.stderr.flush()
        saved = os.dup(2)
        try:
            os.dup2(capture.fileno(), 2)
            sys._debugmallocstats()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        capture.seek(0)
        text = capture.read().decode("ascii", "replace")
    figures: dict[str, float] = {}
    keys = {"# bytes in allocated blocks": "in_blocks_mb",
            "# bytes in available blocks": "free_blocks_mb"}
    for line in text.splitlines():
        name, _, value = line.partition("=")
        name = name.strip()
        if name in keys:
            figures[keys[name]] = round(int(value.replace(",", "").strip()) / 2**20, 2)
        elif name.startswith("# arenas allocated current"):
            figures["arenas"] = int(value.replace(",", "").strip())
        elif name.endswith("bytes/arena"):
            figures["arenas_mb"] = round(int(value.replace(",", "").strip()) / 2**20, 2)
        elif name.endswith("unused pools * 16384 bytes"):
            figures["free_pools_mb"] = round(int(value.replace(",", "").strip()) / 2**20, 2)
    return figures


def _probe(_signum: int, _frame: object) -> None:
    assert _OUT is not None
    gc.collect()
    libc = ctypes.CDLL("libc.so.6")
    libc.malloc_trim(0)
    row: dict[str, object] = {
        "rss_mb": round(_status_mb("VmRSS"), 1),
        "anon_mb": round(_status_mb("RssAnon"), 1),
        "file_mb": round(_status_mb("RssFile"), 1),
        "arenas": _arenas(libc),
        "modules": len(sys.modules),
        "pymalloc": _pymalloc(),
    }
    if "tracemalloc" in sys.modules and sys.modules["tracemalloc"].is_tracing():
        tracer = sys.modules["tracemalloc"]
        row["python_traced_mb"] = round(tracer.get_traced_memory()[0] / 2**20, 2)
        top = int(os.environ.get("HOSTD_HEAPPROBE_TOP", "0") or 0)
        if top:  # where the traced memory was allocated, largest first
            stats = tracer.take_snapshot().statistics("traceback")[:top]
            row["python_top"] = [
                {"kb": round(stat.size / 1024, 1), "count": stat.count,
                 "where": [f"{frame.filename}:{frame.lineno}" for frame in stat.traceback]}
                for stat in stats]
    with open(_OUT, "a", encoding="ascii") as handle:
        handle.write(json.dumps(row) + "\n")


if _OUT and sys.argv[1:2] == ["run"]:
    if os.environ.get("HOSTD_HEAPPROBE_TRACE"):
        import tracemalloc

        tracemalloc.start(int(os.environ["HOSTD_HEAPPROBE_TRACE"]))
    signal.signal(signal.SIGUSR2, _probe)
