"""A protocol core brought to the connected state, as the core's tests start from it."""

from __future__ import annotations

from drivers.link.config import StreamerConfig
from drivers.link.core import LinkCore
from drivers.link.protocol import frame


def connected_core(config: StreamerConfig) -> LinkCore:
    """A core whose own handshake, without identifying the firmware, saw the banner at
    t=0 and had its `N0 M110 N0` acknowledged at 1 ms: ready, the next line is N1."""
    core = LinkCore(config)
    core.begin_connect(0.0, identify=False)
    core.feed("start", 0.0)
    assert core.next_bytes(0.0) == b"\n"
    assert core.next_bytes(0.0) == frame(0, "M110 N0")
    core.feed("ok", 0.001)
    assert core.handshake.done
    return core
