"""The printer link: streams G-code to a Marlin-style printer, every line run once, in order.

A pure protocol core (``core``, with its writer, acknowledgement counter, resync, watchdog
and handshake) decides; an asyncio shell (``streamer``, over ``transport``) moves the bytes.
``protocol`` and ``responses`` are the pure helpers the simulated printer may share; the
link never imports the simulator (import-linter contracts in ``pyproject.toml``).
"""
