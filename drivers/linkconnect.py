"""The streamer's connection half: handshake, firmware defaults, reopening a lost port."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable

from drivers.backoff import Backoff, reconnect
from drivers.linkconfig import StreamerConfig
from drivers.linkcore import LinkCore
from drivers.linkerrors import LinkError, TransportError
from drivers.linkevents import Event
from drivers.linkprofile import Profile, profile_for, tuned
from drivers.linkwaiters import Waiters
from drivers.motionreport import PrinterMotion, parse_motion_report
from drivers.numbering import NumberingProbe, probe_line
from drivers.transport import Transport

log = logging.getLogger("drivers.link")


class Connecting:
    """Mixin of :class:`~drivers.streamer.Streamer`: connecting and reconnecting."""

    # the streamer's fields and methods this mixin uses (annotations only)
    config: StreamerConfig
    core: LinkCore
    profile: Profile | None
    motion: PrinterMotion
    _transport: Transport
    _reopen: Callable[[], Awaitable[Transport]] | None
    _waiters: Waiters
    _started: asyncio.Event
    _probed: asyncio.Event
    _wake: asyncio.Event
    numbering_kept: bool | None
    numbering_last_line: int | None

    @property
    def firmware(self) -> str:
        raise NotImplementedError

    @property
    def capabilities(self) -> dict[str, str]:
        raise NotImplementedError

    @property
    def capable(self) -> frozenset[str]:
        raise NotImplementedError

    def _start_tasks(self) -> None:
        raise NotImplementedError

    async def _control_line(self, command: str, internal: bool = True) -> int:
        raise NotImplementedError

    def _dispatch(self, events: list[Event]) -> None:
        raise NotImplementedError

    async def connect(self, probe_numbering: bool = False) -> None:
        """Wait for ``start`` (or a timeout), then ``M110 N0``, ``M115``, ``M503`` (the
        motion settings, :attr:`motion`; with ``read_motion``) and auto-report.

        ``probe_numbering``: first find out whether the printer still counts the lines
        of an earlier session (:mod:`drivers.numbering`; :attr:`numbering_kept`).
        Raises :class:`LinkError` if the printer does not answer in ``connect_timeout_s``.
        """
        self._start_tasks()
        loop = asyncio.get_running_loop()
        self.core.begin_connect(loop.time())
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(self.config.start_timeout_s):
                await self._started.wait()
        with contextlib.suppress(TransportError):
            await self._transport.write(b"\n")  # end any noise the printer has buffered
        if probe_numbering:
            await self._probe_numbering()
        try:
            async with asyncio.timeout(self.config.connect_timeout_s):
                token, waiter = self._waiters.new()
                self.core.begin_handshake(0, keep_history=False, token=token)
                self._wake.set()
                await waiter
                await self._control_line("M115")
                self._tune()
                if self.config.read_motion:
                    await self._read_motion()
                if "AUTOREPORT_TEMP" in self.capable and self.config.temperature_interval_s > 0:
                    seconds = max(1, round(self.config.temperature_interval_s))
                    await self._control_line(f"M155 S{seconds}")
        except TimeoutError as exc:
            self.core.fail("printer did not answer the connection handshake")
            self._dispatch(self.core.take_events())
            raise LinkError(self.core.error) from exc
        self.core.connected(loop.time())

    async def _probe_numbering(self) -> None:
        """``N1 M105`` before any ``M110``: :attr:`numbering_kept` and
        :attr:`numbering_last_line` from the answer (None when there is none within
        ``connect_timeout_s``). Once refused, the rest of the answer (``Resend``, its
        ``ok``) is awaited for ``resync_quiet_s`` at most: a build that sends no ``ok``
        then costs that long, not an ``ok`` counted for the handshake's ``M110``."""
        probe = self.core.numbering_probe = NumberingProbe(self.config.ok_after_resend)
        self._probed.clear()
        try:
            with contextlib.suppress(TransportError):
                await self._transport.write(probe_line())
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(self.config.connect_timeout_s):
                    while probe.kept is None:
                        await self._probed.wait()
                        self._probed.clear()
                async with asyncio.timeout(self.config.resync_quiet_s):
                    while not probe.done:
                        await self._probed.wait()
                        self._probed.clear()
        finally:
            self.core.numbering_probe = None
        self.numbering_kept, self.numbering_last_line = probe.kept, probe.last_line
        if probe.kept is None:
            log.info("printer line numbering: no answer to the probe (unknown)")
        elif probe.kept:
            log.info("printer line numbering kept from its last host (last line %d): it "
                     "kept its power", probe.last_line)
        else:
            log.info("printer line numbering starts at 1: it booted since its last host")

    def _tune(self) -> None:
        """Settings for the firmware just identified (``M115``), logged."""
        profile = self.profile = profile_for(self.firmware, self.capabilities)
        config, changes = tuned(self.config, profile)
        self.config = config
        self.core.retune(config)
        shown = ", ".join(f"{key}={value}" for key, value in sorted(changes.items()))
        log.info("printer link: %s (%s); rx_buffer=%d bufsize=%d ok_after_resend=%s%s",
                 profile.name, profile.why, config.rx_buffer, config.bufsize,
                 config.ok_after_resend, f"; firmware defaults applied: {shown}" if shown else "")

    async def _read_motion(self) -> None:
        """``M503``: the motion settings in its answer, logged (none reported: none kept)."""
        self.core.transcript = []
        try:
            await self._control_line("M503")
            lines = self.core.transcript
        finally:
            self.core.transcript = None
        self.motion = parse_motion_report(lines)
        if self.motion.reported:
            log.info("printer motion settings (M503): %s", self.motion.describe())
        else:
            log.info("printer reported no motion settings (M503)")

    async def _link_lost(self, reason: str) -> bool:
        """The port failed: report, then try to reopen. True if the link is back."""
        self.core.link_lost(reason)
        self._dispatch(self.core.take_events())
        if self.config.reconnect_attempts > 0:
            with contextlib.suppress(TransportError):
                transport = await reconnect(
                    self._open_again, Backoff(self.config.reconnect_delay_s),
                    errors=(TransportError,), attempts=self.config.reconnect_attempts,
                    wait_first=True)
                self._transport = transport
                with contextlib.suppress(TransportError):
                    # end whatever partial line the printer kept from before the cut
                    await transport.write(b"\n")
                self.core.reopened(asyncio.get_running_loop().time())
                return True
        self.core.fail(f"link lost: {reason}")
        self._dispatch(self.core.take_events())
        return False

    async def _open_again(self) -> Transport:
        if self._reopen is not None:
            return await self._reopen()
        from drivers.transport import open_transport

        return await open_transport(self._transport.name, self._transport.baud)
