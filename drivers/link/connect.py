"""The streamer's connection helpers: reopening a lost port, and what the handshake learnt.

The handshake itself is the core's (:mod:`drivers.link.handshake`): every byte of it comes
out of the core, the shell only moves them.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Awaitable, Callable

from drivers.link.backoff import Backoff, reconnect
from drivers.link.config import StreamerConfig
from drivers.link.errors import TransportError
from drivers.link.handshake import Handshake
from drivers.link.transport import Transport, open_transport

log = logging.getLogger("drivers.link")


class Reconnector:
    """Opens the port again after it was lost: ``reopen`` (default: the same port at the
    same speed), tried ``reconnect_attempts`` times with the backoff of
    :mod:`drivers.link.backoff`."""

    def __init__(self, reopen: Callable[[], Awaitable[Transport]] | None) -> None:
        """``reopen``: how to open the port again (None: the lost transport's port)."""
        self._reopen = reopen

    async def again(self, lost: Transport, config: StreamerConfig) -> Transport | None:
        """A new transport in place of ``lost``, or None (no attempts allowed, or none
        succeeded)."""
        if config.reconnect_attempts <= 0:
            return None

        async def open_again() -> Transport:
            if self._reopen is not None:
                return await self._reopen()
            return await open_transport(lost.name, lost.baud)

        with contextlib.suppress(TransportError):
            return await reconnect(
                open_again, Backoff(config.reconnect_delay_s), errors=(TransportError,),
                attempts=config.reconnect_attempts, wait_first=True)
        return None


def log_connection(handshake: Handshake, config: StreamerConfig) -> None:
    """Log what the handshake learnt: the numbering probe's answer (when asked), the
    firmware's defaults chosen and the motion settings (``M503``)."""
    if handshake.probe_numbering:
        if handshake.numbering_kept is None:
            log.info("printer line numbering: no answer to the probe (unknown)")
        elif handshake.numbering_kept:
            log.info("printer line numbering kept from its last host (last line %d): it "
                     "kept its power", handshake.numbering_last_line)
        else:
            log.info("printer line numbering starts at 1: it booted since its last host")
    profile = handshake.profile
    if profile is not None:
        shown = ", ".join(f"{key}={value}" for key, value in sorted(handshake.changes.items()))
        log.info("printer link: %s (%s); rx_buffer=%d bufsize=%d ok_after_resend=%s%s",
                 profile.name, profile.why, config.rx_buffer, config.bufsize,
                 config.ok_after_resend,
                 f"; firmware defaults applied: {shown}" if shown else "")
    if not config.read_motion or profile is None:
        return
    if handshake.motion.reported:
        log.info("printer motion settings (M503): %s", handshake.motion.describe())
    else:
        log.info("printer reported no motion settings (M503)")
