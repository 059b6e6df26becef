"""A protocol core brought to the connected state, as the core's tests start from it."""

from __future__ import annotations

from drivers.linkconfig import StreamerConfig
from drivers.linkcore import LinkCore
from drivers.protocol import frame


def connected_core(config: StreamerConfig) -> LinkCore:
    """A core that has connected at t=0 and had its `N0 M110 N0` acknowledged at 1 ms."""
    core = LinkCore(config)
    core.begin_connect(0.0)
    core.feed("start", 0.0)
    core.begin_handshake(0, keep_history=False, token=1)
    assert core.next_bytes(0.0) == frame(0, "M110 N0")
    core.feed("ok", 0.001)
    core.connected(0.001)
    return core
