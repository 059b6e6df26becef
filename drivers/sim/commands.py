"""G-code handlers of the simulated printer: what each command does and how long it takes."""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import TYPE_CHECKING

from drivers.sim.report import report_lines

if TYPE_CHECKING:
    from drivers.sim.firmware import Firmware
    from drivers.sim.heater import Heater

FIRMWARE_NAME = "Marlin 2.1.2 (hostd simulator)"

_CODE = re.compile(r"([GMT])(\d+)(?:\.\d+)?(?![\d.])")
_PARAM = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)?")

# G and M codes accepted silently (answered with ok); anything else is an unknown command
_ACCEPTED = frozenset(
    {
        "G10", "G11", "G20", "G21", "G29", "G80", "M17", "M18", "M73", "M84", "M106", "M107",
        "M111", "M117", "M118", "M201", "M203", "M204", "M205", "M206", "M207", "M208", "M209",
        "M221", "M290", "M300", "M420", "M500", "M501", "M502", "M851", "M876", "M900",
        "M999",
    }
)

Params = dict[str, float | None]
Handler = Callable[["Firmware", Params], bool]


def parse(command: str) -> tuple[str, Params] | None:
    """``"G1 X10 F600"`` -> ``("G1", {"X": 10.0, "F": 600.0})``; None if not a G/M/T code.

    A letter without a number maps to None.
    """
    match = _CODE.match(command)
    if not match:
        return None
    code = f"{match.group(1)}{int(match.group(2))}"
    params: Params = {}
    for letter, value in _PARAM.findall(command[match.end() :].upper()):
        params[letter] = float(value) if value else None
    return code, params


def banner() -> list[str]:
    """What Marlin prints after a reset."""
    return ["start", f"echo:{FIRMWARE_NAME}", "echo: Free Memory: 4096  PlannerBufferBytes: 1232"]


def capabilities(fw: Firmware) -> list[str]:
    """M115: the firmware line and the ``Cap:`` lines."""
    caps = {
        "SERIAL_XON_XOFF": 0,
        "BINARY_FILE_TRANSFER": 0,
        "EEPROM": 0,
        "VOLUMETRIC": 1,
        "AUTOREPORT_POS": 0,
        "AUTOREPORT_TEMP": 1,
        "PROGRESS": 0,
        "PRINT_JOB": 1,
        "AUTOLEVEL": 0,
        "RUNOUT": 0,
        "Z_PROBE": 0,
        "LEVELING_DATA": 0,
        "BUILD_PERCENT": 0,
        "SOFTWARE_POWER": 0,
        "TOGGLE_LIGHTS": 0,
        "CASE_LIGHT_BRIGHTNESS": 0,
        "EMERGENCY_PARSER": int(fw.config.emergency_parser),
        "HOST_ACTION_COMMANDS": 0,
        "PROMPT_SUPPORT": 0,
        "SDCARD": 0,
        "AUTOREPORT_SD_STATUS": 0,
        "THERMAL_PROTECTION": 1,
        "ARCS": 1,
        "ADVANCED_OK": int(fw.config.advanced_ok),
    }
    first = (
        f"FIRMWARE_NAME:{FIRMWARE_NAME} SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin"
        " PROTOCOL_VERSION:1.0 MACHINE_TYPE:Simulated Printer EXTRUDER_COUNT:1"
        " UUID:00000000-0000-4000-8000-000000000000"
    )
    return [first] + [f"Cap:{name}:{value}" for name, value in caps.items()]


def execute(fw: Firmware, command: str) -> bool:
    """Run one queued command; returns whether the caller should answer ``ok``.

    The command is logged as executed once its handler has finished (for a move: once it
    is in the planner), just before its ``ok``.
    """
    parsed = parse(command)
    if parsed is None:
        fw.emit(f'echo:Unknown command: "{command}"')
        return True
    code, params = parsed
    handler = _HANDLERS.get(code)
    if handler is None:
        if code not in _ACCEPTED and not code.startswith("T"):
            fw.emit(f'echo:Unknown command: "{command}"')
        fw.log_executed(command)
        return True
    send_ok = handler(fw, params)  # a reset or kill meanwhile raises: not executed, not logged
    fw.log_executed(command)
    return send_ok


def _numbers(params: Params) -> dict[str, float]:
    return {k: v for k, v in params.items() if v is not None}


def _move(fw: Firmware, params: Params) -> bool:
    delta, speed, duration = fw.motion.move_delta(_numbers(params))
    if duration > 0.0:
        fw.stats["moves"] += 1
        fw.times["motion"] += duration
        fw.times["distance_mm"] += duration * speed
        fw.plan_move(delta, speed)
    return True


def _arc(clockwise: bool) -> Handler:
    def handler(fw: Firmware, params: Params) -> bool:
        try:
            chords, length, duration = fw.motion.arc(
                _numbers(params), clockwise, fw.planner.settings
            )
        except ValueError as exc:
            fw.emit(f"echo:{exc}")
            return True
        if duration > 0.0:
            fw.stats["moves"] += 1
            fw.stats["arcs"] += 1
            fw.stats["arc_segments"] += len(chords)
            fw.times["motion"] += duration
            fw.times["distance_mm"] += length
            for delta, speed in chords:
                fw.plan_move(delta, speed)
        return True

    return handler


def _buffer_monitor(fw: Firmware, params: Params) -> bool:
    """M576 [S<seconds>]: report the buffer figures now (auto-reporting is not modelled)."""
    fw.emit(fw.buffer_report())
    return True


def _dwell(fw: Firmware, params: Params) -> bool:
    fw.synchronize()
    values = _numbers(params)
    seconds = values["P"] / 1000.0 if "P" in values else values.get("S", 0.0)
    fw.times["dwell"] += seconds
    fw.wait_sim(seconds)
    return True


def _home(fw: Firmware, params: Params) -> bool:
    fw.synchronize()
    seconds = fw.motion.home("".join(a for a in "XYZ" if a in params))
    fw.times["home"] += seconds
    fw.wait_sim(seconds)
    return True


def _modes(absolute: bool | None, absolute_e: bool | None) -> Handler:
    def handler(fw: Firmware, params: Params) -> bool:
        if absolute is not None:
            fw.motion.set_absolute(absolute)
        if absolute_e is not None:
            fw.motion.absolute_e = absolute_e
        return True

    return handler


def _set_position(fw: Firmware, params: Params) -> bool:
    fw.motion.set_position(_numbers(params))
    return True


def _set_temp(bed: bool, wait: bool) -> Handler:
    def handler(fw: Firmware, params: Params) -> bool:
        values = _numbers(params)
        target = values.get("S", values.get("R"))
        if target is None:
            return True
        heater = fw.bed if bed else fw.hotend
        fw.set_target(heater, target)
        if wait and target > 0.0:
            _wait_heater(fw, heater, heating_only="S" in values)
        return True

    return handler


def _wait_heater(fw: Firmware, heater: Heater, heating_only: bool) -> None:
    """M109/M190: temperature line every simulated second until settled and resided."""
    spec = heater.spec
    now = fw.clock.now()
    if heating_only and heater.temperature(now) > heater.target_c:
        return
    resided_at: float | None = None
    while True:
        now = fw.clock.now()
        if resided_at is None and heater.settled(now, heating_only=False):
            resided_at = now + spec.residency_s
        remaining = "?" if resided_at is None else str(max(0, round(resided_at - now)))
        fw.emit(fw.temperatures() + f" W:{remaining}")
        if resided_at is not None and now >= resided_at - 1e-9:
            return
        if not fw.wait_sim(1.0, cancellable=True):
            return


def _report_temperatures(fw: Firmware, params: Params) -> bool:
    fw.send_ok(fw.temperatures())
    return False


def _position(fw: Firmware, params: Params) -> bool:
    p = fw.motion.position
    fw.emit(
        f"X:{p['X']:.2f} Y:{p['Y']:.2f} Z:{p['Z']:.2f} E:{p['E']:.2f}"
        f" Count X:{round(p['X'] * 80)} Y:{round(p['Y'] * 80)} Z:{round(p['Z'] * 400)}"
    )
    return True


def _firmware_info(fw: Firmware, params: Params) -> bool:
    for line in capabilities(fw):
        fw.emit(line)
    return True


def _report_settings(fw: Firmware, params: Params) -> bool:
    """M503: the settings as the commands that set them, the planner's from its own."""
    for line in report_lines(fw.planner.settings):
        fw.emit(line)
    return True


def _autoreport(fw: Firmware, params: Params) -> bool:
    fw.set_autoreport(_numbers(params).get("S", 0.0))
    return True


def _keepalive(fw: Firmware, params: Params) -> bool:
    seconds = _numbers(params).get("S")
    if seconds is not None and seconds > 0.0:
        fw.keepalive_s = seconds
    return True


def _feed_percent(fw: Firmware, params: Params) -> bool:
    percent = _numbers(params).get("S")
    if percent is not None and percent > 0.0:
        fw.motion.feed_percent = percent
    return True


def _sync(fw: Firmware, params: Params) -> bool:
    fw.synchronize()
    return True


def _quickstop(fw: Firmware, params: Params) -> bool:
    if not fw.config.emergency_parser:  # with the parser it already acted on the bytes
        fw.planner.clear()
    return True


def _kill(fw: Firmware, params: Params) -> bool:
    if fw.config.emergency_parser:  # with the parser it already acted on the bytes
        return True
    fw.kill("M112")
    return False


def _nothing(fw: Firmware, params: Params) -> bool:
    return True


_HANDLERS: dict[str, Handler] = {
    "G0": _move,
    "G1": _move,
    "G2": _arc(clockwise=True),
    "G3": _arc(clockwise=False),
    "G4": _dwell,
    "G28": _home,
    "G90": _modes(True, None),
    "G91": _modes(False, None),
    "M82": _modes(None, True),
    "M83": _modes(None, False),
    "G92": _set_position,
    "M104": _set_temp(bed=False, wait=False),
    "M140": _set_temp(bed=True, wait=False),
    "M109": _set_temp(bed=False, wait=True),
    "M190": _set_temp(bed=True, wait=True),
    "M105": _report_temperatures,
    "M114": _position,
    "M115": _firmware_info,
    "M503": _report_settings,
    "M155": _autoreport,
    "M113": _keepalive,
    "M220": _feed_percent,
    "M400": _sync,
    "M576": _buffer_monitor,
    "M410": _quickstop,
    "M112": _kill,
    "M108": _nothing,
    "M110": _nothing,
}
