"""`hostd tui`: the terminal dashboard over the control socket or MQTT."""

from __future__ import annotations

import argparse

from hostd.commands.target import socket_path


def run(args: argparse.Namespace) -> int:
    """Open the dashboard on one printer's socket, or on a fleet's MQTT broker."""
    from tui.app import Dashboard
    from tui.sources import MqttSource, SocketSource

    if args.mqtt:
        host, _, port = args.mqtt.partition(":")
        source = MqttSource(host, int(port or 1883))
    else:
        source = SocketSource(str(socket_path(args)))
    Dashboard(source).run()
    return 0
