"""`hostd run [--config FILE]`: the daemon, logging to stderr."""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys

from hostd.cli import EXIT_OK, UsageError
from hostd.config import ConfigError, load_config


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
    from hostd.daemon import Daemon

    log = logging.getLogger("hostd")
    log.info("jobs %s, state %s, printer %s", config.jobs.folder, config.state.folder,
             config.printer.port)
    asyncio.run(Daemon(config).run())
    return EXIT_OK
