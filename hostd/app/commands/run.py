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

# glibc's mallopt parameter for the number of malloc arenas (malloc.h: M_ARENA_MAX)
_M_ARENA_MAX = -8
# arenas for the daemon's threads: glibc's default (8 per core) lets each slicing
# thread grow its own heap; two keep a print's peak memory about 10 % lower
MALLOC_ARENAS = 2


def limit_malloc_arenas(arenas: int = MALLOC_ARENAS) -> bool:
    """Cap glibc's malloc arenas before any thread starts; False where there is no glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        return bool(ctypes.CDLL(name).mallopt(_M_ARENA_MAX, arenas))
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
    limit_malloc_arenas()
    from hostd.app.daemon import Daemon

    log = logging.getLogger("hostd")
    log.info("jobs %s, state %s, printer %s", config.jobs.folder, config.state.folder,
             config.printer.port)
    asyncio.run(Daemon(config).run())
    return EXIT_OK
