"""The simulated printer's answer to ``M503``: its motion settings as Marlin 2.1 prints them
(read back by the link's :mod:`drivers.link.motion`)."""

from __future__ import annotations

from drivers.sim.planner import PlannerSettings


def report_lines(settings: PlannerSettings) -> list[str]:
    """Marlin 2.1's ``M503`` answer (before its ``ok``) for a printer whose planner has
    ``settings``, line by line; the settings other than motion are Marlin's defaults."""
    ax, fr = settings.max_acceleration, settings.max_feedrate
    return [
        "echo:; Linear Units:",
        "echo:  G21 ; (mm)",
        "echo:; Temperature Units:",
        "echo:  M149 C ; Units in Celsius",
        "echo:; Steps per unit:",
        "echo:  M92 X80.00 Y80.00 Z400.00 E93.00",
        "echo:; Maximum feedrates (units/s):",
        f"echo:  M203 X{fr[0]:.2f} Y{fr[1]:.2f} Z{fr[2]:.2f} E{fr[3]:.2f}",
        "echo:; Maximum Acceleration (units/s2):",
        f"echo:  M201 X{ax[0]:.2f} Y{ax[1]:.2f} Z{ax[2]:.2f} E{ax[3]:.2f}",
        "echo:; Acceleration (units/s2) (P<print-accel> R<retract-accel> T<travel-accel>):",
        f"echo:  M204 P{settings.acceleration:.2f} R{settings.retract_acceleration:.2f}"
        f" T{settings.travel_acceleration:.2f}",
        "echo:; Advanced (B<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate>"
        " J<junc_dev>):",
        f"echo:  M205 B20000.00 S0.00 T0.00 J{settings.junction_deviation:.3f}",
        "echo:; Home offset:",
        "echo:  M206 X0.00 Y0.00 Z0.00",
        "echo:; Hotend PID:",
        "echo:  M301 P22.20 I1.08 D114.00",
    ]
