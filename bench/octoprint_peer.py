"""OctoPrint's virtual printer on a pseudo-terminal: a firmware emulation nobody here wrote.

Run only with the Python of a virtual environment of its own that has OctoPrint
installed (``bench/stream_throughput.py --peer octoprint`` creates one under
``bench/.cache/``). OctoPrint is AGPL: this benchmark tool imports it in that separate
process and nothing of it is copied into, or required by, the package::

    bench/.cache/octoprint-venv/bin/python bench/octoprint_peer.py --resend-ratio 2 \\
        --log executed.txt

Prints the pseudo-terminal's path on the first line of standard output, then serves until
standard input closes, each direction of the wire paced to ``--baud`` (a serial
port's 8N1 bytes: 25,000 bytes/s at 250000 baud). ``--resend-ratio P`` is the
emulation's own setting: every ``100 // P``-th line received it reports an error and
asks for the next line, as it does.
Its error texts are set to Marlin's (``Error:checksum mismatch, Last Line: N``, the last
line the emulation took), the rest of its settings are its defaults but for the
simulated errors at fixed line numbers, turned off. Every move it queues (``G0``/``G1``)
is written to ``--log``, one a line, as it queued it.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
import tty
from typing import Any, ClassVar


class Settings:
    """The plugin settings the emulation reads (``get``, ``get_boolean``, ...)."""

    def __init__(self, values: dict[str, Any], folder: str) -> None:
        self.values = values
        self.folder = folder

    def get(self, path: list[str], merged: bool = False) -> Any:
        value: Any = self.values
        for key in path:
            value = value[key]
        return value

    def get_boolean(self, path: list[str]) -> bool:
        return bool(self.get(path))

    def get_int(self, path: list[str]) -> int:
        return int(self.get(path))

    def get_float(self, path: list[str]) -> float:
        return float(self.get(path))

    def global_get_basefolder(self, name: str) -> str:
        path = os.path.join(self.folder, name)
        os.makedirs(path, exist_ok=True)
        return path


class Profiles:
    """A printer profile manager with the default profile only."""

    def get_current_or_default(self) -> dict[str, Any]:
        return {"volume": {"width": 200, "depth": 200, "height": 200,
                           "formFactor": "rectangular", "origin": "lowerleft"},
                "heatedBed": True, "heatedChamber": False, "extruder": {"count": 1}}


def main() -> int:
    """Serve the emulation on a pseudo-terminal until standard input closes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resend-ratio", type=int, default=0)
    parser.add_argument("--log", required=True)
    parser.add_argument("--baud", type=int, default=250000,
                        help="wire speed both ways (8N1: baud / 10 bytes/s; 0: unlimited)")
    args = parser.parse_args()
    rate = args.baud / 10

    from octoprint.plugins.virtual_printer import VirtualPrinterPlugin, virtual
    from octoprint.plugins.virtual_printer.virtual import VirtualPrinter

    class NoPlugins:
        """The plugin manager the emulation asks for hooks: none are installed."""

        def get_hooks(self, name: str) -> dict[str, Any]:
            return {}

    virtual.plugin_manager = NoPlugins  # (OctoPrint's own is not started here)

    class Logged(VirtualPrinter):  # type: ignore[misc]
        """The emulation, with Marlin's error texts and its queued moves logged."""

        moves: ClassVar[list[str]] = []

        def _error(self, error: str, *fmt: Any, **kwargs: Any) -> str:
            texts = {"checksum_mismatch": "checksum mismatch",
                     "checksum_missing": "No Checksum with line number",
                     "lineno_mismatch": "Line Number is not Last Line Number+1",
                     "lineno_missing": "No Line Number with checksum"}
            if error in texts:
                return f"Error:{texts[error]}, Last Line: {self.lastN}"
            return str(super()._error(error, *fmt, **kwargs))

        def _gcode_G0(self, data: str) -> None:
            self.moves.append(data.strip())
            super()._gcode_G0(data)

        _gcode_G1 = _gcode_G0

    values = VirtualPrinterPlugin().get_settings_defaults()
    values.update(resend_ratio=args.resend_ratio, simulated_errors=[], enable_eeprom=False,
                  sendWait=False)
    folder = tempfile.mkdtemp(prefix="octoprint-peer-")
    printer = Logged(Settings(values, folder), Profiles(), folder, read_timeout=0.5)

    master, slave = os.openpty()
    tty.setraw(slave)
    print(os.ttyname(slave), flush=True)

    def wire(free_at: list[float], size: int) -> None:
        """Wait for ``size`` bytes' time on one direction of the wire."""
        if rate:
            now = time.monotonic()
            free_at[0] = max(now, free_at[0]) + size / rate
            if free_at[0] > now:
                time.sleep(free_at[0] - now)

    to_printer_wire, to_host_wire = [0.0], [0.0]

    def to_printer() -> None:
        # one line per write, as a serial port delivers them to OctoPrint's own host: the
        # emulation takes one line from each write it is given (two lines in one write
        # left the second waiting for the next write)
        pending = b""
        while True:
            try:
                pending += os.read(master, 4096)
            except OSError:
                return
            *whole, pending = pending.split(b"\n")
            for line in whole:
                data = line + b"\n"
                wire(to_printer_wire, len(data))
                # held back until the emulation's receive queue has room for the whole
                # line, as flow control would: its write() waits for room holding the
                # lock its refusals take, and both stood still until the write timed out
                queue = printer.incoming
                if queue is None:
                    return
                with queue.not_full:  # (its mutex: the emulation's get() notifies it)
                    while queue._qsize() and queue._qsize() + len(data) > queue.maxsize:
                        queue.not_full.wait(0.05)
                while data:
                    written = printer.write(data) or 0
                    data = data[written:]

    def to_host() -> None:
        while printer.outgoing is not None:
            line = printer.readline()
            if line:
                data = line if line.endswith(b"\n") else line + b"\n"
                wire(to_host_wire, len(data))
                os.write(master, data)

    for target in (to_printer, to_host):
        threading.Thread(target=target, daemon=True).start()
    sys.stdin.read()  # until the benchmark closes it
    printer.close()
    with open(args.log, "w", encoding="utf-8") as f:
        f.write("".join(f"{m}\n" for m in Logged.moves))
    return 0


if __name__ == "__main__":
    sys.exit(main())
