"""`hostd tui`: the terminal dashboard over the control socket, or the fleet view over MQTT."""

from __future__ import annotations

import argparse
import os
from typing import Any

from hostd.app.cli import UsageError
from hostd.app.commands.target import socket_path


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd tui``."""
    group = p.add_mutually_exclusive_group()
    group.add_argument("--config", metavar="FILE")
    group.add_argument("--socket", metavar="PATH")
    group.add_argument("--mqtt", metavar="HOST[:PORT]",
                       help="the fleet view on a broker (a cluster: HOST:PORT,HOST:PORT,...)")
    p.add_argument("--username", default="", help="broker user name (with --mqtt)")
    p.add_argument("--password", default=None,
                   help="broker password (with --mqtt; default: $HOSTD_MQTT_PASSWORD)")
    p.add_argument("--tls", action="store_true", help="connect to the broker over TLS")
    p.add_argument("--cafile", metavar="FILE",
                   help="with --tls: the CA (PEM) of the broker's certificate (default: system's)")
    p.add_argument("--certfile", metavar="FILE",
                   help="with --tls: this client's certificate (PEM), with --keyfile")
    p.add_argument("--keyfile", metavar="FILE", help="with --tls: the key of --certfile (PEM)")
    p.add_argument("--farm", metavar="URL,...",
                   help="with --mqtt: the farm queue on these NATS servers beside the printers")
    p.add_argument("--redraw-s", metavar="S", default=None,
                   help="for a slow link: draw the layer picture and the event log (and the "
                        "fleet table) at most once every S seconds (default: "
                        "$HOSTD_TUI_REDRAW_S, else as the status comes)")


def run(args: argparse.Namespace) -> int:
    """Open the dashboard on one printer's socket, or the fleet view on an MQTT broker."""
    from tui.app import redraw_seconds
    from tui.sources import MqttSource, SocketSource, parse_brokers, tls_context

    try:
        redraw_s = redraw_seconds(args.redraw_s)
    except ValueError as exc:
        raise UsageError(f"--redraw-s (or $HOSTD_TUI_REDRAW_S): {exc}") from exc
    files = args.cafile or args.certfile or args.keyfile
    mqtt_only = args.username or args.password is not None or args.tls or files
    if args.mqtt:
        from tui.fleet import FleetApp

        try:
            brokers = parse_brokers(args.mqtt)
        except ValueError as exc:
            raise UsageError(f"--mqtt: {exc}") from exc
        password = args.password
        if password is None:
            password = os.environ.get("HOSTD_MQTT_PASSWORD", "")
        if files and not args.tls:
            raise UsageError("--cafile, --certfile and --keyfile go with --tls")
        try:
            tls = tls_context(args.cafile or "", args.certfile or "", args.keyfile or "") \
                if args.tls else False
        except ValueError as exc:
            raise UsageError(f"--tls: {exc}") from exc
        FleetApp(MqttSource(brokers, username=args.username, password=password, tls=tls),
                 redraw_s=redraw_s, farm=_farm_feed(args.farm)).run()
        return 0
    if args.farm:
        raise UsageError("--farm goes with --mqtt HOST[:PORT] (the fleet view)")
    if mqtt_only:
        raise UsageError("--username, --password, --tls and its files go with --mqtt HOST[:PORT]")
    from tui.app import Dashboard

    Dashboard(SocketSource(str(socket_path(args))), redraw_s=redraw_s).run()
    return 0


def _farm_feed(servers: str | None) -> Any:
    """The farm queue's rows for the fleet view (``--farm URL,...``), or None."""
    if not servers:
        return None
    from hostd.config import FarmConfig
    from hostd.farm.feed import FarmFeed

    urls = tuple(url.strip() for url in servers.split(",") if url.strip())
    return FarmFeed(FarmConfig(servers=urls))
