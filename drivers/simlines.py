"""Marlin's checks of one received line (``queue.cpp``), as a pure function."""

from __future__ import annotations

import re
from collections.abc import Callable
from functools import reduce
from operator import xor
from typing import NamedTuple

from drivers.protocol import xor_bytes

ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
ERR_CHECKSUM = "checksum mismatch, Last Line: "
ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "

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


def check_line(raw: bytes, last_n: int) -> LineCheck:
    """Check one line (without its terminator) as Marlin does, given the last line number.

    Leading blanks are skipped and a ``;`` comment dropped. Only lines starting with ``N``
    are checked: first the number (must be ``last_n + 1`` unless the line holds ``M110``),
    then the checksum (XOR of every byte before the last ``*``). ``M110 N<m>`` sets the
    last line to ``m``, numbered or not; without a parameter a numbered M110 sets it to
    its own number.
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
    if is_m110:
        param = command.find("N", command.find("M110") + 4)
        if param >= 0:
            last_n = strtol(command[param + 1 :])
    return LineCheck("", command, number, last_n)


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
    line, noise on a real board; the lines behind it are accepted as usual).
    Returns the lines to emit and whether the refusal is followed by its ``ok``
    where the firmware sends one after a resend. Renumbering (``M110``) and
    unnumbered lines draw nothing.
    """
    if number is None or "M110" in command:
        return [], False
    lines: list[str] = []
    if fires("resend"):
        lines.append(f"Resend: {last_n}")
    refused = fires("refuse")
    if refused:
        lines += [f"Error:{ERR_CHECKSUM}{last_n}", f"Resend: {last_n + 1}"]
    return lines, refused
