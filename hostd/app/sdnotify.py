"""The systemd notify protocol over ``NOTIFY_SOCKET``: readiness, status text and the watchdog.

The daemon calls ``notify("READY=1", "STATUS=...")`` once it serves, runs
:func:`watchdog` as a task for as long as it lives, and calls
``notify("STOPPING=1")`` when it begins a clean shutdown. Outside systemd
(``NOTIFY_SOCKET`` unset) every call is a cheap no-op.
"""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Mapping

from hostd.api import Snapshot, duration
from hostd.publishing.status import StatusHub


def _socket_address(env: Mapping[str, str]) -> str | None:
    """The datagram address named by ``NOTIFY_SOCKET``: a path, or ``\\0name`` when abstract."""
    address = env.get("NOTIFY_SOCKET", "")
    if address.startswith("@"):
        return "\0" + address[1:]
    if address.startswith("/"):
        return address
    return None


def notify(*messages: str, env: Mapping[str, str] | None = None) -> bool:
    """Send ``KEY=VALUE`` messages to the service manager in one datagram.

    Returns True when the datagram was sent, False when ``NOTIFY_SOCKET`` is
    unset or unusable or the send failed (the service manager is gone).
    ``env`` defaults to ``os.environ``.
    """
    address = _socket_address(os.environ if env is None else env)
    if address is None or not messages:
        return False
    payload = "\n".join(messages).encode()
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
        try:
            sock.sendto(payload, address)
        except OSError:
            return False
    return True


def watchdog_interval(env: Mapping[str, str] | None = None) -> float | None:
    """The watchdog timeout in seconds from ``WATCHDOG_USEC``, or None when not enabled.

    Also None when ``WATCHDOG_PID`` names another process (the watchdog is not ours).
    """
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC", "")
    pid = env.get("WATCHDOG_PID", "")
    if pid and pid != str(os.getpid()):
        return None
    try:
        value = int(usec)
    except ValueError:
        return None
    return value / 1_000_000 if value > 0 else None


def status_line(snapshot: Snapshot) -> str:
    """A one-line summary of a snapshot for ``systemctl status`` (``STATUS=``)."""
    job = snapshot.job
    if snapshot.state == "error":
        text = f"error: {snapshot.error or 'unknown'}"
    elif job is None:
        text = snapshot.state
    else:
        text = (f"{snapshot.state} {job.name} layer {job.layer + 1} of {job.layers} "
                f"({job.progress:.0%})")
        if job.eta_s is not None:
            text += f", ETA {duration(job.eta_s, hours=True)}"
    if snapshot.queue:
        text += f", {len(snapshot.queue)} queued"
    if snapshot.interrupted:
        text += f", {len(snapshot.interrupted)} interrupted"
    if not snapshot.printer.connected:
        text += ", printer not connected"
    return " ".join(text.split())


async def _ping(interval: float, env: Mapping[str, str] | None) -> None:
    """Send WATCHDOG=1 every ``interval`` seconds while the event loop is alive."""
    while True:
        notify("WATCHDOG=1", env=env)
        await asyncio.sleep(interval)


async def _report_status(hub: StatusHub, env: Mapping[str, str] | None) -> None:
    """Send STATUS=<summary> whenever the summary of the newest snapshot changes."""
    last = status_line(hub.current)
    notify(f"STATUS={last}", env=env)
    async for snapshot in hub.snapshots():
        line = status_line(snapshot)
        if line != last:
            notify(f"STATUS={line}", env=env)
            last = line


async def watchdog(hub: StatusHub, env: Mapping[str, str] | None = None) -> None:
    """Keep systemd informed until cancelled: WATCHDOG=1 at half the interval, STATUS= on change.

    Returns at once when ``NOTIFY_SOCKET`` is unset (nothing to tell).
    """
    if _socket_address(os.environ if env is None else env) is None:
        return
    interval = watchdog_interval(env)
    async with asyncio.TaskGroup() as group:
        if interval is not None:
            group.create_task(_ping(interval / 2, env), name="sdnotify-watchdog")
        group.create_task(_report_status(hub, env), name="sdnotify-status")
