"""Sanity checks for resend requests: which line did the printer really ask for?"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.link.responses import Response, parse_response


def edit_distance(a: str, b: str) -> int:
    """Levenshtein distance between two short strings."""
    previous = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        current = [i]
        for j, cb in enumerate(b, 1):
            current.append(min(previous[j] + 1, current[j - 1] + 1,
                               previous[j - 1] + (ca != cb)))
        previous = current
    return previous[-1]


def resolve_resend(
    digits: str,
    candidates: Sequence[int],
    error_last_line: int | None = None,
    max_distance: int = 2,
) -> int | None:
    """The line a resend request most plausibly names, or ``None`` if none fits.

    ``digits`` is the number as received (``"034497"``); ``candidates`` are the line
    numbers the printer can legitimately ask for (sent and unacknowledged, plus the next
    line to send); ``error_last_line`` is the ``Last Line`` of the error just before, when
    one was received. A request that names a candidate exactly (without a leading zero) is
    taken as is, unless the ``Last Line`` of the error names another candidate (then
    neither is trusted); otherwise the ``Last Line`` of the error decides if it is a candidate;
    otherwise the candidate whose digits differ least (at most ``max_distance`` edits, and
    a unique best) is taken. Noise can drop or change digits, so a request is never obeyed
    blindly.
    """
    pool = set(candidates)
    if not pool or not digits.isdigit():
        return None
    requested = int(digits)
    clean = not (len(digits) > 1 and digits.startswith("0"))
    if error_last_line is not None and error_last_line + 1 in pool:
        if clean and requested in pool and requested != error_last_line + 1:
            # one of the two was garbled: a replay from too early would drop lines the
            # printer holds (their oks still to come), from too late skip one; the next
            # refusal, of the next line on the wire or of a probe, will say
            return None
        return error_last_line + 1
    if clean and requested in pool:
        return requested
    if clean and error_last_line is not None and requested == error_last_line + 1:
        # the error and the request agree on a line that cannot be asked for: the printer
        # lost its numbering (a reset whose banner was lost, an M110 run as something
        # else), which no repair explains. Read as a garbled request for a line on the
        # wire ("1" for 41), it was answered by replaying that line, refused the same way,
        # for ever (the caller decides, from the line named)
        return None
    scored = sorted((edit_distance(digits, str(n)), n) for n in pool)
    best_distance, best = scored[0]
    if best_distance > max_distance:
        return None
    if len(scored) > 1 and scored[1][0] == best_distance:
        return None
    return best


# Marlin's messages for a refused line, as they start the text after ``Error:``
_LINE_ERRORS = (
    "checksum mismatch",
    "Line Number is not Last Line Number+1",
    "No Checksum with line number",
    "No Line Number with checksum",
)


def recover(response: Response) -> Response:
    """A line garbled by noise, read as what it most likely was.

    ``ok``, ``Error:``, ``Resend:`` and ``start`` with one character changed are
    recognised, and so is an ``Error:`` whose message for a refused line has one
    character changed (a lost ``ok`` stalls the window; an error not known for a line
    error leaves the ``Resend`` after it unannounced, and the ``ok`` after that would
    count for a line). Anything less certain is left as it is.
    """
    if response.kind == "error" and response.error_kind == "other":
        return _recover_line_error(response)
    if response.kind != "other":
        return response
    raw = response.raw
    if len(raw) == 2 and edit_distance(raw.lower(), "ok") == 1:
        return parse_response("ok")
    if len(raw) > 3 and raw[3:4] in ("N", "T", "P", "B"):
        # "ok" or the space after it changed ("oj T:20.0 ...", "ok!T:20.0 ...")
        changed = edit_distance(raw[:2].lower(), "ok") + (raw[2] != " ")
        if changed == 1:
            return parse_response("ok " + raw[3:])
    for word in ("Error:", "Resend:"):
        head = raw[: len(word)]
        if len(raw) > len(word) and edit_distance(head.lower(), word.lower()) == 1:
            fixed = parse_response(word + raw[len(word):])
            if fixed.kind != "other":
                return fixed
    if len(raw) == 5 and edit_distance(raw.lower(), "start") == 1:
        return parse_response("start")
    return response


def _recover_line_error(response: Response) -> Response:
    """An ``Error:`` line whose text differs from a line-error message in one character,
    read as that message; any other error as it is."""
    raw = response.raw
    # unstripped: a first character turned into a blank by noise keeps its place
    body = raw[6:] if raw[:6].lower() == "error:" else response.text
    for message in _LINE_ERRORS:
        head = body[: len(message)]
        if len(head) == len(message) and edit_distance(head.lower(), message.lower()) == 1:
            return parse_response("Error:" + message + body[len(message):])
    return response
