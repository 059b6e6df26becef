"""The text forms the daemon, its commands and both dashboards share: the one duration
formatter and the one progress bar.

Standard library only and nothing else imported, so a command that prints a summary
(``hostd slice``) does not load the control API's schema for two functions;
:mod:`hostd.api` re-exports both for its clients (the dashboards import only it).
"""

from __future__ import annotations


def duration(seconds: float | None, *, hours: bool = False, words: bool = False,
             unknown: str = "--") -> str:
    """A time span as the daemon, its commands and the dashboard write it.

    ``2:03`` or ``1:02:03``; with ``hours`` always ``0:02:03`` (a column of one form);
    with ``words`` ``2m 03s`` or ``1h 02m 03s``; ``unknown`` for None. A clock counts the
    whole seconds passed (0.9 s left reads ``0:00``); words round to the nearest second
    (a total). A negative span reads as zero. This is the project's one duration
    formatter outside the G-code (the slicer writes its header's own fixed form).
    """
    if seconds is None:
        return unknown
    whole = round(seconds) if words else int(seconds)
    minutes, secs = divmod(max(whole, 0), 60)
    hour, minutes = divmod(minutes, 60)
    if words:
        return f"{hour}h {minutes:02d}m {secs:02d}s" if hour else f"{minutes}m {secs:02d}s"
    if hour or hours:
        return f"{hour}:{minutes:02d}:{secs:02d}"
    return f"{minutes}:{secs:02d}"


def bar(fraction: float, width: int, *, ascii: bool = False, empty: str | None = None) -> str:
    """A progress bar of exactly ``width`` cells, the fraction clamped to 0..1.

    Block glyphs to an eighth of a cell (``█████▌····``) for the dashboard, or with
    ``ascii`` whole cells of ``#`` and ``-`` (``#####-----``) for a plain terminal or a
    log. ``empty`` fills the rest (default ``·``, or ``-`` with ``ascii``). This is the
    project's one progress bar: the commands' lines and both dashboards draw it.
    """
    width = max(0, width)
    fill, partial = ("#", "") if ascii else ("█", " ▏▎▍▌▋▊▉")
    steps = max(1, len(partial))
    full, part = divmod(round(max(0.0, min(1.0, fraction)) * width * steps), steps)
    text = fill * full + (partial[part] if part else "")
    return text + (empty or ("-" if ascii else "·")) * (width - len(text))
