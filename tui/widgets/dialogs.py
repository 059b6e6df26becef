"""Modal screens of the dashboard: confirm, help, log filter, objects of the plate, retune."""

from __future__ import annotations

from typing import Any, ClassVar

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, OptionList, Static
from textual.widgets.option_list import Option

from hostd.api import duration
from tui.format import metres

DIALOG_CSS = """
%s { align: center middle; }
%s > Vertical {
    width: auto; min-width: 40; max-width: 90%%; height: auto; max-height: 90%%;
    border: round $accent; padding: 0 1; background: $panel;
}
"""

HELP = """\
[b]Keys[/b]
 p  pause the print (the nozzle lifts off the part)
 r  resume
 c  cancel the job (asks to confirm)
 R  resume an interrupted job
 o  bodies of the plate: highlight, cancel one, undo
 t  retune infill density and field, temperatures
 f  infill field as a colour map under the layer
 /  filter the event log
 !  emergency stop: M112 (asks to confirm)
 ?  this help
 q  quit the dashboard (the print goes on);
    from the fleet view, q or Esc goes back to it

The layer picture: walls, infill, skin and support in
their colours; what this layer has printed is bright,
what is still to come is dim. Mouse: click a key in
the footer."""


class ConfirmScreen(ModalScreen[bool]):
    """A question answered with y (True) or n / Escape (False)."""

    DEFAULT_CSS = DIALOG_CSS % ("ConfirmScreen", "ConfirmScreen")
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("y", "answer(True)", "Yes"),
        Binding("n,escape", "answer(False)", "No"),
    ]

    def __init__(self, question: str) -> None:
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Static(self.question, id="question")
            yield Static("[b]y[/b] yes   [b]n[/b] no", id="choices")

    def action_answer(self, answer: bool) -> None:
        self.dismiss(answer)


class HelpScreen(ModalScreen[None]):
    """The keys and what the picture shows."""

    DEFAULT_CSS = DIALOG_CSS % ("HelpScreen", "HelpScreen") + """
    HelpScreen > Vertical { width: 60; max-width: 100%; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("escape,q,question_mark", "close", "Close")]

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Static(HELP, id="help")
            yield Static("[dim]Esc closes[/dim]")

    def action_close(self) -> None:
        self.dismiss(None)


class FilterScreen(ModalScreen[str | None]):
    """Asks for the text the event log is filtered by (empty: everything)."""

    DEFAULT_CSS = DIALOG_CSS % ("FilterScreen", "FilterScreen")
    BINDINGS: ClassVar[list[Binding]] = [Binding("escape", "close", "Close")]

    def __init__(self, current: str) -> None:
        super().__init__()
        self.current = current

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Static("Show log lines containing (empty: all):")
            yield Input(self.current, id="filter")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value.strip())

    def action_close(self) -> None:
        self.dismiss(None)


class ObjectsScreen(ModalScreen[tuple[str, int] | None]):
    """The bodies of the plate; moving the cursor highlights one in the picture.

    Dismisses with ("cancel", body), ("restore", body) or None.
    """

    DEFAULT_CSS = DIALOG_CSS % ("ObjectsScreen", "ObjectsScreen")
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("c", "choose('cancel')", "Cancel body"),
        Binding("u", "choose('restore')", "Undo cancel"),
        Binding("escape,o", "close", "Close"),
    ]

    def __init__(self, layer: dict[str, Any], on_highlight) -> None:
        super().__init__()
        self.plate = layer
        self.on_highlight = on_highlight

    def compose(self) -> ComposeResult:
        options = []
        cancelled = {item["object"]: item["from_layer"] for item in self.plate["cancelled"]}
        for body in range(self.plate["body_count"]):
            if body in cancelled:
                first = cancelled[body]
                undo = " (u undoes)" if first >= self.plate["next_unsliced"] else ""
                note = f"cancelled from layer {first + 1}{undo}"
            else:
                note = "printing"
            options.append(Option(f"body {body}  {note}", id=str(body)))
        with Vertical():
            yield Static("[b]Bodies of the plate[/b]  c cancel · u undo · Esc close")
            yield OptionList(*options, id="bodies")

    def on_mount(self) -> None:
        self.on_highlight(0)

    def on_option_list_option_highlighted(self, event: OptionList.OptionHighlighted) -> None:
        self.on_highlight(int(event.option.id))

    def action_choose(self, what: str) -> None:
        index = self.query_one(OptionList).highlighted
        if index is not None:
            self.dismiss((what, index))

    def action_close(self) -> None:
        self.dismiss(None)


class RetuneScreen(ModalScreen[dict[str, Any] | None]):
    """Edit infill density and field, nozzle and bed temperatures; dismisses with the changes.

    ``settings`` holds the current values by flat key (``estimate``'s reply).
    """

    DEFAULT_CSS = DIALOG_CSS % ("RetuneScreen", "RetuneScreen") + """
    RetuneScreen Input { width: 30; }
    """
    BINDINGS: ClassVar[list[Binding]] = [Binding("escape", "close", "Close")]
    FIELDS = (("infill.density", "infill density %"), ("infill.field", "infill field"),
              ("nozzle_temp", "nozzle °C"), ("bed_temp", "bed °C"))

    def __init__(self, settings: dict[str, Any], fields: list[str]) -> None:
        super().__init__()
        self.settings = settings
        self.fields = fields

    def _shown(self, key: str) -> str:
        value = self.settings.get(key, "")
        if key == "infill.density" and isinstance(value, int | float):
            return f"{value * 100:g}"
        return f"{value:g}" if isinstance(value, float) else str(value)

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Static("[b]Retune the layers not sliced yet[/b]  Enter: next / done")
            for key, label in self.FIELDS:
                yield Static(label)
                yield Input(self._shown(key), id=key.replace(".", "-"))
            yield Static(f"[dim]fields: {', '.join(self.fields)}[/dim]", id="names")
            yield Static("", id="error")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        inputs = list(self.query(Input))
        at = inputs.index(event.input)
        if at + 1 < len(inputs):
            inputs[at + 1].focus()
            return
        changes: dict[str, Any] = {}
        label = ""
        try:
            for key, label in self.FIELDS:  # noqa: B007 (named in the error)
                text = self.query_one("#" + key.replace(".", "-"), Input).value.strip()
                if text == self._shown(key):
                    continue
                if key == "infill.field":
                    changes[key] = text
                elif key == "infill.density":
                    changes[key] = float(text) / 100
                else:
                    changes[key] = float(text)
        except ValueError:
            self.query_one("#error", Static).update(f"[red]{label}: a number, please[/red]")
            return
        self.dismiss(changes or None)

    def action_close(self) -> None:
        self.dismiss(None)


def retune_question(changes: dict[str, Any], reply: dict[str, Any]) -> str:
    """The confirmation of a retune: the changes and the new ETA and filament."""
    new = reply.get("retuned") or {}
    shown = ", ".join(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}"
                      for k, v in changes.items())
    return (
        f"Retune from layer {reply['from_layer'] + 1}: {shown}\n"
        f"ETA {duration(reply.get('eta_s'))} -> [b]{duration(new.get('eta_s'))}[/b]\n"
        f"filament {metres(reply.get('filament_total_mm'))} -> "
        f"[b]{metres(new.get('filament_total_mm'))}[/b]\n"
        "Apply?"
    )
