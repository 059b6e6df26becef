"""`hostd run`'s glibc settings: which blocks are mapped on their own, in a fresh process."""

from __future__ import annotations

import ctypes.util
import json
import subprocess
import sys

import pytest

# In a fresh interpreter: tune glibc's malloc, then count the blocks glibc has mapped
# on their own (mallinfo2's hblks) while a 1 MB and then an 8 MB block are held.
_PROBE = r"""
import ctypes, ctypes.util, json
from hostd.app.commands.run import tune_malloc

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
        "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL(ctypes.util.find_library("c"))
libc.mallinfo2.restype = MallInfo2
tuned = tune_malloc()
before = libc.mallinfo2().hblks
small = bytearray(1 << 20)
with_small = libc.mallinfo2().hblks
large = bytearray(8 << 20)
with_large = libc.mallinfo2().hblks
del large
after_large = libc.mallinfo2().hblks
print(json.dumps([tuned, before, with_small, with_large, after_large]))
"""


def _glibc_has_mallinfo2() -> bool:
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        return hasattr(ctypes.CDLL(name), "mallinfo2")
    except OSError:
        return False


@pytest.mark.skipif(not _glibc_has_mallinfo2(), reason="needs glibc 2.33 or later")
def test_blocks_under_4_mb_come_from_the_heap_and_larger_ones_are_mapped_and_returned():
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                         check=True, timeout=60)
    tuned, before, with_small, with_large, after_large = json.loads(out.stdout)
    assert tuned is True
    # a 1 MB block: from the heap (the fixed trim threshold left the mmap one at 128 kB)
    assert with_small == before
    # an 8 MB block: mapped on its own, and unmapped once freed
    assert with_large == before + 1
    assert after_large == before
