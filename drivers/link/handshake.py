"""The protocol core's handshake: from a port just opened to a link ready to stream.

:class:`Handshake` owns the steps and what they learn. Each step is a state of the core,
each answer an event it is fed; every byte comes out of the core's writer:

1. ``BANNER``: the ``start`` banner of a board that resets on open, or
   ``start_timeout_s`` without one (a board that kept its power, or prints none).
2. A newline, ending whatever noise the printer has half a line of.
3. ``NUMBERING`` (when asked): ``N1 M105`` before any ``M110``, whose answer tells
   whether the board still counts an earlier session's lines (:mod:`drivers.link.numbering`);
   awaited ``connect_timeout_s``, then the rest of a refusal ``resync_quiet_s``.
4. ``RENUMBER``: ``N0 M110 N0`` (the form both readings of ``M110`` accept), nothing
   after it until its ``ok``.
5. ``IDENTIFY``: ``M115``; the firmware's name and capabilities choose the link's
   defaults (:mod:`drivers.link.profile`).
6. ``MOTION`` (``read_motion``): ``M503``, whose answer gives the motion settings
   (:mod:`drivers.link.motion`).
7. ``AUTOREPORT``: ``M155 S<n>`` when the firmware offers temperature auto-reports.

Steps 4 to 7 must be answered within ``connect_timeout_s`` of step 4, or the link fails.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from drivers.link.events import Connected
from drivers.link.motion import PrinterMotion, parse_motion_report
from drivers.link.numbering import NumberingProbe, probe_line
from drivers.link.profile import Profile, profile_for, tuned
from drivers.link.responses import Response

if TYPE_CHECKING:  # the core holds the handshake; the handshake asks it
    from drivers.link.core import LinkCore

# tokens of the handshake's own lines (the shell's tokens are positive)
_RENUMBER, _IDENTIFY, _MOTION, _AUTOREPORT = -1, -2, -3, -4


class Step(StrEnum):
    """Where the handshake is."""

    IDLE = "idle"
    BANNER = "banner"
    NUMBERING = "numbering"
    RENUMBER = "renumber"
    IDENTIFY = "identify"
    MOTION = "motion"
    AUTOREPORT = "autoreport"
    DONE = "done"


class Handshake:
    """The handshake's steps and what they learn (see the module docstring)."""

    def __init__(self, core: LinkCore) -> None:
        """Not begun."""
        self.core = core
        self.step = Step.IDLE
        self.probe_numbering = False
        self.identify = True
        self.probe: NumberingProbe | None = None  # out, its answer not read whole yet
        # whether the printer still counted an earlier session's lines (None: not probed,
        # or no answer), and the last of them
        self.numbering_kept: bool | None = None
        self.numbering_last_line: int | None = None
        self.profile: Profile | None = None  # the firmware defaults chosen
        self.changes: dict[str, Any] = {}  # the settings they changed
        self.motion = PrinterMotion()  # what M503 reported
        self.transcript: list[str] | None = None  # every line received while M503 is out
        self._deadline = math.inf
        self._extended = False  # the probe's wait extended once (the rest of its answer)

    @property
    def done(self) -> bool:
        """The link is ready to stream."""
        return self.step == Step.DONE

    def begin(self, probe_numbering: bool, identify: bool) -> None:
        """The port is open: wait for the banner (the core's watchdog times it out)."""
        self.step = Step.BANNER
        self.probe_numbering = probe_numbering
        self.identify = identify
        self._deadline = math.inf

    def banner(self, now: float) -> None:
        """The banner came, or its wait ended: a newline, then the probe or the ``M110``."""
        if self.step != Step.BANNER:
            return
        self.core.writer.queue_raw(b"\n")  # end any noise the printer has buffered
        if not self.probe_numbering:
            self._renumber(now)
            return
        self.probe = NumberingProbe(self.core.config.ok_after_resend)
        self.core.writer.queue_raw(probe_line())
        self.step = Step.NUMBERING
        self._deadline = now + self.core.config.connect_timeout_s
        self._extended = False

    def take(self, response: Response, now: float) -> bool:
        """A response while the numbering probe is out: True when it answers the probe (the
        link must not count it)."""
        probe = self.probe
        assert probe is not None
        taken = probe.take(response)
        if probe.done:
            self._numbered(now)
        elif probe.kept is not None and not self._extended:
            # refused: the rest of the answer (Resend, its ok) within resync_quiet_s at
            # most; a build that sends no ok then costs that long, not an ok counted for
            # the handshake's M110
            self._extended = True
            self._deadline = now + self.core.config.resync_quiet_s
        return taken

    def acked(self, token: int) -> None:
        """One of the handshake's own lines was acknowledged."""
        core = self.core
        now = core.watchdog.last_rx
        if token == _RENUMBER:
            if not self.identify:
                self._finish(now)
                return
            self.step = Step.IDENTIFY
            core.queue_control("M115", internal=True, token=_IDENTIFY)
        elif token == _IDENTIFY:
            profile = self.profile = profile_for(core.firmware, core.capabilities)
            config, self.changes = tuned(core.config, profile)
            core.retune(config)
            if config.read_motion:
                self.step = Step.MOTION
                self.transcript = []
                core.queue_control("M503", internal=True, token=_MOTION)
            else:
                self._autoreport(now)
        elif token == _MOTION:
            self.motion = parse_motion_report(self.transcript or [])
            self.transcript = None
            self._autoreport(now)
        elif token == _AUTOREPORT:
            self._finish(now)

    def tick(self, now: float) -> None:
        """Let time pass: the probe's wait, the handshake's deadline."""
        if now < self._deadline:
            return
        if self.step == Step.NUMBERING:
            if not self._extended:
                self._extended = True  # no answer: the rest of one, had it come late
                self._deadline = now + self.core.config.resync_quiet_s
                return
            self._numbered(now)
        elif self.step != Step.DONE:
            self._deadline = math.inf
            self.core.fail("printer did not answer the connection handshake")

    def _numbered(self, now: float) -> None:
        probe = self.probe
        assert probe is not None
        self.probe = None
        self.numbering_kept, self.numbering_last_line = probe.kept, probe.last_line
        self._renumber(now)

    def _renumber(self, now: float) -> None:
        self.step = Step.RENUMBER
        self._deadline = now + self.core.config.connect_timeout_s
        self.core.begin_handshake(0, keep_history=False, token=_RENUMBER)

    def _autoreport(self, now: float) -> None:
        config = self.core.config
        if "AUTOREPORT_TEMP" in self.core.capable and config.temperature_interval_s > 0:
            self.step = Step.AUTOREPORT
            seconds = max(1, round(config.temperature_interval_s))
            self.core.queue_control(f"M155 S{seconds}", internal=True, token=_AUTOREPORT)
        else:
            self._finish(now)

    def _finish(self, now: float) -> None:
        self.step = Step.DONE
        self._deadline = math.inf
        self.core.connected(now)
        self.core.emit(Connected())
