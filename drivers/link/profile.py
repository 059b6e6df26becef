"""Firmware defaults for the link: what the ``M115`` banner and capabilities tell of a board."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from drivers.link.config import StreamerConfig

# Marlin's receive ring when XON/XOFF is offered (only built with RX_BUFFER_SIZE >= 1024)
_XON_XOFF_RX = 1023
_MARLIN = re.compile(r"marlin\s*(?:bugfix-)?v?(\d+)\.(\d+)", re.IGNORECASE)


@dataclass(frozen=True)
class Profile:
    """A family of firmware and the link settings it calls for.

    ``settings`` are ``StreamerConfig`` fields; ``why`` says where they come from.
    """

    name: str
    settings: Mapping[str, Any]
    why: str


def profile_for(firmware: str, capabilities: Mapping[str, str]) -> Profile:
    """The profile for an ``M115`` ``FIRMWARE_NAME`` value and its ``Cap:`` lines.

    - Marlin 2.1 and later: 128-byte receive ring, ``BUFSIZE`` 4, an ``ok`` after every
      ``Resend`` (unconditional since 2.1).
    - Marlin 2.0: the same buffers; the ``ok`` after a ``Resend`` goes through
      ``ok_to_send()`` and is normally sent (Marlin#18955), so it is expected.
    - Prusa firmware (Marlin 1.1 lineage): 128-byte ring, 4 commands, ``ok`` after a
      ``Resend`` (``ClearToSend``); mesh bed levelling (``G80``) and filament changes run
      long, so the silence tolerated during long commands is doubled.
    - Anything else: Marlin 2.1's values, the safest guess for a Marlin-like board.

    ``Cap:SERIAL_XON_XOFF:1`` means a receive buffer of at least 1024 bytes, so the window
    may hold 1023 bytes; ``Cap:ADVANCED_OK:1`` lets the link learn ``BUFSIZE`` from each ok.
    """
    low = firmware.lower()
    settings: dict[str, Any] = {"rx_buffer": 127, "bufsize": 4, "ok_after_resend": True}
    if "prusa" in low:
        name, why = "prusa", "Prusa firmware"
        settings["long_command_timeout_s"] = 1800.0
    elif (match := _MARLIN.search(firmware)) is not None:
        major, minor = int(match.group(1)), int(match.group(2))
        if (major, minor) >= (2, 1):
            name, why = "marlin-2.1", f"Marlin {major}.{minor}"
        elif major == 2:
            name, why = "marlin-2.0", "Marlin 2.0"
        else:
            name, why = "marlin-1", f"Marlin {major}.{minor}"
    else:
        name, why = "generic", "unknown firmware, Marlin 2.1 values"
    if capabilities.get("SERIAL_XON_XOFF") == "1":
        settings["rx_buffer"] = _XON_XOFF_RX
        why += ", XON/XOFF (receive buffer >= 1024)"
    if capabilities.get("ADVANCED_OK") == "1":
        settings["learn_bufsize"] = True
        why += ", advanced ok"
    return Profile(name, settings, why)


def tuned(config: StreamerConfig, profile: Profile) -> tuple[StreamerConfig, dict[str, Any]]:
    """``config`` with the profile's settings, except those the user chose (``explicit``,
    or set to other than the default in code), or none when ``firmware_defaults`` is off;
    also returns what changed."""
    if not config.firmware_defaults:
        return config, {}
    defaults = StreamerConfig()
    changes = {key: value for key, value in profile.settings.items()
               if key not in config.explicit and getattr(config, key) == getattr(defaults, key)
               and value != getattr(config, key)}
    return (replace(config, **changes) if changes else config), changes
