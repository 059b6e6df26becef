"""CPU time and memory of a running process and its descendants, read from /proc (Linux)."""

from __future__ import annotations

import os
from pathlib import Path

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def _stat_fields(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat after the command name (field 3 first); None if gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def _children(pid: int) -> list[int] | None:
    """Child pids of ``pid`` from /proc/PID/task/*/children; None where the kernel lacks it."""
    tasks = Path(f"/proc/{pid}/task")
    kids: list[int] = []
    try:
        for task in tasks.iterdir():
            kids += [int(v) for v in (task / "children").read_text().split()]
    except FileNotFoundError:
        return None if tasks.exists() else []
    except OSError:
        return []
    return kids


def descendants(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (children, grandchildren, ...)."""
    if _children(pid) is None:
        return _descendants_by_scan(pid)
    found: list[int] = []
    frontier = [pid]
    while frontier:
        kids = _children(frontier.pop()) or []
        found += kids
        frontier += kids
    return found


def _descendants_by_scan(pid: int) -> list[int]:
    """Descendants of ``pid`` from the parent pids of every process in /proc."""
    parent_of: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(int(entry.name))
            if fields is not None:
                parent_of[int(entry.name)] = int(fields[1])
    found: list[int] = []
    frontier = [pid]
    while frontier:
        current = frontier.pop()
        kids = [child for child, parent in parent_of.items() if parent == current]
        found += kids
        frontier += kids
    return found


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid``, its reaped children and its live descendants, s."""
    total = 0.0
    fields = _stat_fields(pid)
    if fields is None:
        return 0.0
    # fields[11..14] = utime, stime, cutime, cstime (stat fields 14-17)
    total += sum(int(v) for v in fields[11:15])
    for child in descendants(pid):
        child_fields = _stat_fields(child)
        if child_fields is not None:
            total += int(child_fields[11]) + int(child_fields[12])
    return total / CLOCK_TICKS


def status_kb(pid: int, key: str) -> int:
    """A ``kB`` value of /proc/PID/status (``VmRSS``, ``VmHWM``); 0 if the process is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        return 0
    return 0


def pss_kb(pid: int) -> int:
    """Proportional set size of ``pid`` in kB: its resident pages, each shared page divided
    among the processes sharing it (so forked workers are not counted twice); falls back
    to VmRSS where /proc/PID/smaps_rollup is missing; 0 if the process is gone."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1])
    except FileNotFoundError:
        return status_kb(pid, "VmRSS")
    except OSError:
        return 0
    return status_kb(pid, "VmRSS")


def tree_pss_mb(pid: int, include_root: bool = True) -> float:
    """Memory of ``pid``'s process tree without double counting shared pages (PSS), MB."""
    pids = descendants(pid) + ([pid] if include_root else [])
    return sum(pss_kb(p) for p in pids) * 1024 / 1e6
