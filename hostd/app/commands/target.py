"""Locate a running daemon's control socket from `--socket` or `--config`."""

from __future__ import annotations

import argparse
from pathlib import Path

SOCKET_NAME = "hostd.sock"


def add_target(parser: argparse.ArgumentParser) -> None:
    """Options that locate a running daemon: its config file or its control socket."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--config", metavar="FILE", help="daemon configuration (TOML)")
    group.add_argument("--socket", metavar="PATH", help="the daemon's control socket")


def socket_path(args: argparse.Namespace) -> Path:
    """The control socket named by ``--socket``, or the one in the configured state folder."""
    if getattr(args, "socket", None):
        return Path(args.socket)
    from hostd.config import load_config

    config = load_config(getattr(args, "config", None))
    return Path(config.state.folder) / SOCKET_NAME
