"""Slicing settings for the connected printer's motion: the acceleration its firmware reported.

The slicer's time estimate (``;TIME:``, ``M73``, each layer's time, so the ETA) models
the printer's planner with ``acceleration``. A printer owner rarely knows it, so the
value the firmware reported at connect (``M503``: ``M204 P`` capped by ``M201 X`` and
``Y``, :mod:`drivers.link.motion`) is used unless the configuration's ``[slicing]``
or the job's own ``NAME.toml`` set it.
"""

from __future__ import annotations

from collections.abc import Mapping

from drivers.link.motion import PrinterMotion
from hostd.config import Config
from slicer.settings import SliceSettings, setting_range


def learned_acceleration(motion: PrinterMotion | None) -> float | None:
    """The printing acceleration the printer reported (mm/s², within the slicer's range),
    or None when it reported none."""
    value = motion.printing_acceleration() if motion is not None else None
    if value is None or value <= 0.0:
        return None
    lowest, highest = setting_range("acceleration")
    return min(max(value, lowest or value), highest or value)


def acceleration_given(config: Config, mapping: Mapping[str, object]) -> bool:
    """Whether a job's settings ``mapping`` (flat keys) chose the acceleration: the
    configuration's ``[slicing]`` gave it, or the job's value differs from the
    configuration's (its ``NAME.toml`` or a reprint set it)."""
    if "acceleration" in config.slicing_given:
        return True
    value = mapping.get("acceleration", config.slicing.acceleration)
    return value != config.slicing.acceleration


def with_printer_motion(
    config: Config, mapping: Mapping[str, object], settings: SliceSettings,
    motion: PrinterMotion | None,
) -> SliceSettings:
    """``settings`` (a job's, from ``mapping``) with the printer's reported acceleration,
    unless the acceleration was chosen (:func:`acceleration_given`) or none was reported."""
    learned = learned_acceleration(motion)
    if learned is None or acceleration_given(config, mapping):
        return settings
    return SliceSettings.from_mapping({"acceleration": learned}, base=settings)


def motion_note(config: Config, motion: PrinterMotion | None) -> str:
    """What the slicer's time model takes from the printer, for the log at connect."""
    learned = learned_acceleration(motion)
    if "acceleration" in config.slicing_given:
        return (f"acceleration {config.slicing.acceleration:g} mm/s² from [slicing]"
                + (f" (the printer reported {learned:g})" if learned is not None else ""))
    if learned is None:
        return (f"acceleration {config.slicing.acceleration:g} mm/s² (the default: the "
                "printer reported none)")
    return f"acceleration {learned:g} mm/s² learned from the printer (M503)"
