"""Marlin's checks of one received line (``queue.cpp``), as a pure function."""

from __future__ import annotations

import re
from collections.abc import Callable
from functools import reduce
from operator import xor
from typing import NamedTuple

from drivers.link.protocol import xor_bytes

ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
ERR_CHECKSUM = "checksum mismatch, Last Line: "
ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "

RESEND_OK = ""  # in spurious_replies: the ok after a Resend (where the firmware sends one)

_LEADING_N = re.compile(r"^N[-+]?\d*\s*")
_STRTOL = re.compile(r"\s*([-+]?\d+)")


class LineCheck(NamedTuple):
    """The outcome of checking one line.

    ``error`` is one of the ``ERR_*`` prefixes (the caller appends the last line number)
    or ``""``; ``command`` is the text to queue (``""``: nothing to run); ``number`` is
    the line's own number (None when unnumbered); ``last_n`` the last line number after
    the line.
    """

    error: str
    command: str
    number: int | None
    last_n: int


def strtol(text: str) -> int:
    """C's ``strtol(text, NULL, 10)``: leading blanks, optional sign, digits; else 0."""
    match = _STRTOL.match(text)
    return int(match.group(1)) if match else 0


def check_line(raw: bytes, last_n: int, m110_by_line: bool = False) -> LineCheck:
    """Check one line (without its terminator) as Marlin does, given the last line number.

    Leading blanks are skipped and a ``;`` comment dropped. Only lines starting with ``N``
    are checked: first the number (must be ``last_n + 1`` unless the line holds ``M110``),
    then the checksum (XOR of every byte before the last ``*``). ``M110 N<m>`` sets the
    last line to ``m``, numbered or not; without a parameter a numbered M110 sets it to
    its own number; with ``m110_by_line`` (an emulation's reading) a numbered M110 sets it
    to its own number whatever the parameter says.
    """
    if raw[:1] == b"N" and b";" not in raw:
        quick = _fast_check(raw, last_n)  # the usual line: numbered, no comment, no blanks
        if quick is not None:
            return quick
    text = raw.decode("latin-1").split(";", 1)[0].lstrip(" ")
    if not text.strip():
        return LineCheck("", "", None, last_n)
    is_m110 = "M110" in text
    number: int | None = None
    if text.startswith("N"):
        space = text.find(" ")
        digits = text[1:space] if space > 1 else ""
        fast = digits.isdigit() and digits.isascii()  # "N<digits> ...": no regex needed
        number = int(digits) if fast else strtol(text[1:])
        if number != last_n + 1 and not is_m110:
            return LineCheck(ERR_LINE_NO, "", number, last_n)
        star = text.rfind("*")
        if star < 0:
            return LineCheck(ERR_NO_CHECKSUM, "", number, last_n)
        if strtol(text[star + 1 :]) != xor_bytes(text[:star].encode("latin-1")):
            return LineCheck(ERR_CHECKSUM, "", number, last_n)
        last_n = number
        if fast and space < star:
            command = text[space:star].strip()
        else:
            command = _LEADING_N.sub("", text[:star]).strip()
    else:
        command = text.split("*", 1)[0].strip()
    if is_m110 and not (m110_by_line and number is not None):
        last_n = m110_value(command, last_n)
    return LineCheck("", command, number, last_n)


def m110_value(command: str, last_n: int) -> int:
    """The last line number ``M110 N<m>`` sets (``last_n`` when it has no parameter)."""
    param = command.find("N", command.find("M110") + 4)
    return strtol(command[param + 1 :]) if param >= 0 else last_n


def silently_dropped(check: LineCheck, last_n: int) -> bool:
    """Whether a firmware that drops duplicates silently ignores this refused line: one
    numbered as the last line received, or one below it (no ok, no error)."""
    return (check.error == ERR_LINE_NO and check.number is not None
            and last_n - 1 <= check.number <= last_n)


def _fast_check(raw: bytes, last_n: int) -> LineCheck | None:
    """:func:`check_line` for ``N<digits> <command>*<digits>`` without ``M110`` (``None``:
    another form, checked the general way)."""
    space = raw.find(b" ")
    star = raw.rfind(b"*")
    if space < 2 or star < space or b"M110" in raw:
        return None
    digits = raw[1:space]
    tail = raw[star + 1:]
    if not (digits.isdigit() and tail.isdigit()):
        return None
    number = int(digits)
    if number != last_n + 1:
        return LineCheck(ERR_LINE_NO, "", number, last_n)
    if int(tail) != reduce(xor, raw[:star], 0):
        return LineCheck(ERR_CHECKSUM, "", number, last_n)
    return LineCheck("", raw[space:star].strip().decode("latin-1"), number, number)


def spurious_replies(
    fires: Callable[[str], bool], command: str, number: int | None, last_n: int
) -> tuple[list[str], bool]:
    """The seeded noise that follows an intact numbered line ``last_n``, as Marlin shows it.

    ``fires(kind)`` draws the fault ``resend`` (a request for the line that just
    arrived; its own ok follows when it runs, so every received line is still
    answered by exactly one ok) and then ``refuse`` (Marlin's refusal of an intact
    line, noise on a real board; the lines behind it are accepted as usual), then
    ``refuse_next`` (an emulation's refusal of the next line, not yet sent: the same
    lines, but their ``ok`` is the only one this line gets).
    Returns the lines to emit, :data:`RESEND_OK` where the ``ok`` after a resend goes
    (on a firmware that sends one), and whether the line's own ``ok`` is withheld.
    Renumbering (``M110``) and unnumbered lines draw nothing.
    """
    if number is None or "M110" in command:
        return [], False
    lines: list[str] = []
    if fires("resend"):
        lines.append(f"Resend: {last_n}")
    if fires("refuse"):
        lines += [f"Error:{ERR_CHECKSUM}{last_n}", f"Resend: {last_n + 1}", RESEND_OK]
    withheld = fires("refuse_next")
    if withheld:
        lines += [f"Error:{ERR_CHECKSUM}{last_n}", f"Resend: {last_n + 1}", RESEND_OK]
    return lines, withheld
