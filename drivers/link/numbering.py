"""Whether the printer kept its line numbering from its last host: a probe before ``M110``.

A board that booted since its last host (power cut, reset button, a reboot while no
host had the port open, so that its ``start`` banner went unread) counts lines from
0 again; one that kept its power still counts the lines of the session before. The
probe is ``N1 M105``, written before the handshake's ``M110`` renumbers: the booted
board takes it (``ok``), the other refuses it (``Error:Line Number is not Last Line
Number+1, Last Line: L`` with ``L`` > 0, then ``Resend: L+1`` and, on firmware that
does, ``ok``), and nothing is carried out. Only an ``ok`` with the temperatures (or
right after a report line) answers the probe: a plain one may be that of a line the last
host left in the printer's queue.
"""

from __future__ import annotations

from drivers.link.protocol import frame
from drivers.link.responses import Response

PROBE_COMMAND = "M105"  # harmless wherever the printer is: a temperature report


def probe_line() -> bytes:
    """The probe as written: line 1, checksummed, no ``M110`` before it."""
    return frame(1, PROBE_COMMAND)


class NumberingProbe:
    """Reads the printer's answer to :func:`probe_line`.

    :meth:`take` is given every response while the probe is out and keeps those
    that answer it (the link must not count them). ``kept``: None until answered,
    then True when the printer still counted an earlier session's lines
    (``last_line`` of them), False when it expected line 1 (it booted since).
    ``done`` once the whole answer is read (the ``ok`` after a ``Resend`` too,
    when ``ok_after_resend``).
    """

    def __init__(self, ok_after_resend: bool) -> None:
        self.kept: bool | None = None
        self.last_line: int | None = None
        self.done = False
        self._ok_after_resend = ok_after_resend
        self._refused = False
        self._reported = False

    def take(self, response: Response) -> bool:
        """True when ``response`` is (part of) the answer to the probe."""
        if self.done:
            return False
        kind = response.kind
        if kind == "start":  # it booted while the probe was out (and lost the probe)
            self.kept, self.last_line, self.done = False, 0, True
            return False  # the banner is the link's too
        if kind == "error" and response.line is not None and not self._refused:
            # refused by number, or by a checksum noise broke: the Last Line tells either way
            self._refused = True
            self.last_line = response.line
            self.kept = response.line > 0
            return True
        if kind == "resend" and self._refused:
            self.done = not self._ok_after_resend
            return True
        reported, self._reported = self._reported, kind == "temperature"
        if kind == "temperature":  # an M105 answered on a line of its own, its ok next
            return False
        if kind == "ok":
            if self._refused:
                self.done = True  # the ok after the Resend
                return True
            if not (response.temperatures or reported):
                # no report in it: an ok of a line the last host left in the printer's
                # queue, not the probe's (M105 answers with the temperatures)
                return False
            self.kept, self.last_line, self.done = False, 0, True  # line 1 was expected
            return True
        return False  # busy echoes, a boot banner: the link's as ever
