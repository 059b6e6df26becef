"""Resuming within a layer: where to continue, and the moves that bring the nozzle back there."""

from __future__ import annotations

from drivers.link.protocol import strip_comment

# feed rates (mm/min) of the moves back, when the layer's own commands do not name one
TRAVEL_FEED = 6000.0
LOWER_FEED = 600.0


def resume_line(acked: int, replay: int) -> int:
    """The command of the interrupted layer a resume continues at.

    ``acked`` commands of the layer were acknowledged before the interruption.
    When the printer kept its power (only the host stopped) every acknowledged
    command was carried out or is still in its buffers: continue at the first
    one not acknowledged (``replay`` = 0). When the printer itself reset, the
    commands its buffers held are lost: go back ``replay`` commands (its command
    buffer plus its planner blocks), no further.
    """
    return max(0, acked - max(0, replay))


def reentry_moves(done: list[str]) -> tuple[str, ...]:
    """Moves that bring the nozzle from the resume block's lifted position back to where
    the commands ``done`` (the layer's first commands, not sent again) left it.

    The resume block leaves the nozzle homed in X and Y, lifted above the part,
    extrusion relative (``M83``). Then: the retraction in force after ``done``
    (if the filament was retracted there), a travel at the lifted height to
    the last X Y (so no printed path is touched), the drop to the layer's Z,
    and the feed rate in force. Lines of text, without comments; none when
    ``done`` is empty (the layer begins as sliced).
    """
    x = y = z = feed = None
    travel = TRAVEL_FEED
    retraction: str | None = None
    for line in done:
        command = strip_comment(line)
        if not command:
            continue
        words = command.split()
        if words[0] not in ("G0", "G1"):
            continue
        values = {word[0]: word[1:] for word in words[1:] if word[:1] in "XYZEF"}
        x = values.get("X", x)
        y = values.get("Y", y)
        z = values.get("Z", z)
        if "F" in values:
            feed = values["F"]
            if words[0] == "G0":
                travel = float(values["F"])
        if "E" in values and "X" not in values and "Y" not in values:
            retraction = command if float(values["E"]) < 0 else None  # retract or prime
    if not done:
        return ()
    moves: list[str] = []
    if retraction is not None:
        moves.append(retraction)
    if x is not None and y is not None:
        moves.append(f"G0 F{travel:g} X{x} Y{y}")
    if z is not None:
        moves.append(f"G0 F{LOWER_FEED:g} Z{z}")
    if feed is not None:
        moves.append(f"G1 F{feed}")
    return tuple(moves)
