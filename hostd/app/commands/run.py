"""`hostd run [--config FILE]`: the daemon, logging to stderr."""

from __future__ import annotations

import argparse
import asyncio
import ctypes
import ctypes.util
import logging
import sys

from hostd.app.cli import EXIT_OK, UsageError
from hostd.config import ConfigError, load_config

# glibc's mallopt parameters (malloc.h): the number of malloc arenas, the free
# memory at the top of a heap above which the heap is trimmed, and the size from
# which a block is mapped on its own
_M_ARENA_MAX = -8
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
# arenas for the daemon's threads: glibc's default (8 per core) lets each slicing
# thread grow its own heap; two keep a print's peak memory about 10 % lower
MALLOC_ARENAS = 2
# glibc raises its trim threshold to twice the largest block it gave back to the
# system (up to 64 MB), and ``malloc_trim`` never trims the top of a thread's arena:
# a thread's heap then kept 6-8 MB free at its top for jobs on end. Fixed at
# glibc's default, each thread's heap is trimmed when it frees a large block.
TRIM_THRESHOLD = 128 * 1024
# Setting the trim threshold also stops glibc raising its mmap threshold, which then
# stays at 128 kB: every array above it is mapped afresh and its pages faulted in
# on first use. That made the gyroid ball's whole-model pass (611,498 faces) 1.9 s
# instead of 1.1 s. Blocks up to 4 MB come from the heaps again (1.2 s); larger ones
# are still mapped on their own and go back to the system when freed.
MMAP_THRESHOLD = 4 * 1024 * 1024


def tune_malloc(
    arenas: int = MALLOC_ARENAS, trim_threshold: int = TRIM_THRESHOLD,
    mmap_threshold: int = MMAP_THRESHOLD,
) -> bool:
    """Cap glibc's malloc arenas and fix its trim and mmap thresholds, before any
    thread starts; False where there is no glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
        return all([bool(mallopt(_M_ARENA_MAX, arenas)),
                    bool(mallopt(_M_TRIM_THRESHOLD, trim_threshold)),
                    bool(mallopt(_M_MMAP_THRESHOLD, mmap_threshold))])
    except (OSError, AttributeError):  # not glibc: nothing to set
        return False


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd run``."""
    p.add_argument("--config", metavar="FILE", help="configuration file (TOML)")


def run(args: argparse.Namespace) -> int:
    """Load the configuration (refusing bad keys with exit 2) and serve until a signal."""
    try:
        config = load_config(args.config)
    except ConfigError as exc:
        raise UsageError(f"bad configuration: {exc}") from exc
    logging.basicConfig(
        level=logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    logging.getLogger("watchfiles").setLevel(logging.WARNING)
    tune_malloc()
    from hostd.app.daemon import Daemon

    log = logging.getLogger("hostd")
    log.info("jobs %s, state %s, printer %s", config.jobs.folder, config.state.folder,
             config.printer.port)
    asyncio.run(Daemon(config).run())
    return EXIT_OK
