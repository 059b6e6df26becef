"""Classification of the lines a Marlin-style printer sends back (pure, never raises)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

ResponseKind = Literal[
    "ok", "resend", "busy", "error", "temperature", "start", "wait", "capability", "echo", "other"
]

# error_kind values of an "error" Response
ERROR_CHECKSUM = "checksum"
ERROR_LINE_NUMBER = "line_number"
ERROR_NO_CHECKSUM = "no_checksum"
ERROR_NO_LINE_NUMBER = "no_line_number"
ERROR_HALTED = "halted"
ERROR_STOPPED = "stopped"
ERROR_OTHER = "other"


_RESEND = re.compile(r"^(?:resend|rs)\s*[:\s]\s*N?(\d+)", re.IGNORECASE)
_LAST_LINE = re.compile(r"last\s*line\s*:\s*(\d+)", re.IGNORECASE)
# a temperature item: T, T0..T9, B, C (chamber), P (probe), A (ambient), R (redundant), L, M
_TEMP = re.compile(
    r"(?<![\w@])([TBCPARLM]\d?|T\d\d):\s*(-?\d+(?:\.\d+)?)(?:\s*/\s*(-?\d+(?:\.\d+)?))?"
)
_POWER = re.compile(r"(?<!\w)([TBC]?\d?@\d?):\s*(-?\d+)")
_ADV_OK = re.compile(r"(?<!\w)([NPB])(-?\d+)")
_CAP = re.compile(r"^Cap:([A-Za-z0-9_]+):(\S*)")


@dataclass(frozen=True)
class Response:
    """One line received from the printer, classified.

    ``kind`` is one of ok, resend, busy, error, temperature, start, wait, capability, echo,
    other. Fields not meaningful for a kind keep their defaults.

    - ``line``: for ``resend`` the requested line number; for ``error`` the ``Last Line``
      it reports (when present); for an advanced ``ok`` its ``N``.
    - ``digits``: the requested number exactly as received (``"034497"``), so a caller can
      judge whether digits were lost to noise.
    - ``planner_free`` / ``queue_free``: advanced ok ``P`` and ``B``.
    - ``temperatures``: ``{"T": (actual, target), "B": (...), "T0": ...}``; target is
      ``None`` when the report gives none. Filled for ``temperature`` and for ``ok T:...``.
    - ``power``: heater power fields, ``{"@": 64, "B@": 127}``.
    - ``text``: error text (after ``Error:``), busy reason, echo text, or the raw line.
    - ``error_kind``: for errors one of checksum, line_number, no_checksum, no_line_number,
      halted, stopped, other.
    - ``name`` / ``value``: capability name and value (``Cap:EMERGENCY_PARSER:1`` gives
      ``("EMERGENCY_PARSER", "1")``; the M115 banner gives ``("FIRMWARE_NAME", rest)``).
    """

    kind: ResponseKind
    raw: str = ""
    line: int | None = None
    digits: str = ""
    planner_free: int | None = None
    queue_free: int | None = None
    temperatures: dict[str, tuple[float, float | None]] = field(default_factory=dict, compare=False)
    power: dict[str, int] = field(default_factory=dict, compare=False)
    text: str = ""
    error_kind: str = ""
    name: str = ""
    value: str = ""

    @property
    def has_temperatures(self) -> bool:
        """True when the line carried at least one temperature reading."""
        return bool(self.temperatures)


def parse_response(text: str) -> Response:
    """Classify one received line (without or with its line ending). Never raises."""
    raw = text.strip("\r\n\x00 \t")
    low = raw.lower()
    if not raw:
        return Response("other", raw)
    if low == "ok" or low.startswith("ok ") or low.startswith("ok:"):
        return _parse_ok(raw)
    if low.startswith(("resend", "rs")):
        match = _RESEND.match(raw)
        if match:
            digits = match.group(1)
            return Response("resend", raw, line=int(digits), digits=digits)
        if low.startswith("resend"):
            return Response("other", raw, text=raw)
    if low.startswith("error:") or raw.startswith("!!"):
        return _parse_error(raw)
    if low.startswith("echo:busy:") or low.startswith("busy:"):
        return Response("busy", raw, text=raw.split(":", 2)[-1].strip())
    if low == "start":
        return Response("start", raw)
    if low == "wait":
        return Response("wait", raw)
    if raw.startswith("Cap:"):
        match = _CAP.match(raw)
        if match:
            return Response("capability", raw, name=match.group(1), value=match.group(2))
    if raw.startswith("FIRMWARE_NAME:"):
        return Response("capability", raw, name="FIRMWARE_NAME", value=raw[14:].strip())
    temps = _temperatures(raw)
    if temps and _looks_like_report(raw):
        return Response("temperature", raw, temperatures=temps, power=_power(raw))
    if low.startswith("echo:"):
        return Response("echo", raw, text=raw[5:].strip())
    return Response("other", raw, text=raw)


def _parse_ok(raw: str) -> Response:
    rest = raw[2:].lstrip(" :")
    temps = _temperatures(rest)
    line = planner = queue = None
    if not temps:
        for key, number in _ADV_OK.findall(rest):
            value = int(number)
            if key == "N":
                line = value
            elif key == "P":
                planner = value
            else:
                queue = value
    return Response(
        "ok", raw, line=line, planner_free=planner, queue_free=queue,
        temperatures=temps, power=_power(rest) if temps else {},
    )


def _parse_error(raw: str) -> Response:
    body = raw[2:].strip() if raw.startswith("!!") else raw[6:].strip()
    low = body.lower()
    if "checksum mismatch" in low:
        kind = ERROR_CHECKSUM
    elif "line number is not" in low:
        kind = ERROR_LINE_NUMBER
    elif "no checksum" in low:
        kind = ERROR_NO_CHECKSUM
    elif "no line number" in low:
        kind = ERROR_NO_LINE_NUMBER
    elif "halted" in low or "kill" in low:
        kind = ERROR_HALTED
    elif "stopped" in low or "m999" in low:
        kind = ERROR_STOPPED
    else:
        kind = ERROR_OTHER
    match = _LAST_LINE.search(body)
    line = int(match.group(1)) if match else None
    return Response("error", raw, line=line, digits=match.group(1) if match else "",
                    text=body, error_kind=kind)


def _looks_like_report(raw: str) -> bool:
    """A temperature report starts with a sensor item (``T:``, ``B:``, ``T0:``...)."""
    head = raw.lstrip()
    return bool(re.match(r"^(?:[TBC]\d?|T\d\d):\s*-?\d", head))


def _temperatures(text: str) -> dict[str, tuple[float, float | None]]:
    found: dict[str, tuple[float, float | None]] = {}
    for name, actual, target in _TEMP.findall(text):
        if name in found:
            continue
        try:
            found[name] = (float(actual), float(target) if target else None)
        except ValueError:
            continue
    if not any(name[0] in "TB" for name in found):
        return {}
    return found


def _power(text: str) -> dict[str, int]:
    found = {name: int(value) for name, value in _POWER.findall(text)}
    return found
