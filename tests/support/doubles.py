"""The one recording controller the control socket, MQTT and dashboard tests share."""

from __future__ import annotations

from typing import Any

from hostd.publishing.status import CommandError


class RecordingController:
    """A controller that records every command and carries out none.

    Commands named in ``refuse`` are refused with their reason (by default
    ``cancel``: no job is printing), every command when ``refuse_all`` gives a
    reason; ``set`` with a ``boom`` argument fails as a bug in a controller
    would. Any other command is answered ``{"done": cmd}``.
    """

    def __init__(self, refuse: dict[str, str] | None = None,
                 refuse_all: str | None = None) -> None:
        self.calls: list[tuple[str, dict[str, Any]]] = []
        self.refuse = {"cancel": "no job is printing"} if refuse is None else refuse
        self.refuse_all = refuse_all

    @property
    def commands(self) -> list[str]:
        """The names of the commands received, in order."""
        return [cmd for cmd, _args in self.calls]

    async def handle(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        self.calls.append((cmd, args))
        if self.refuse_all is not None:
            raise CommandError(self.refuse_all)
        if cmd in self.refuse:
            raise CommandError(self.refuse[cmd])
        if cmd == "set" and "boom" in args:
            raise ZeroDivisionError("controller bug")
        return {"done": cmd}
