"""The simulated printer: a Marlin-like firmware on a pseudo-terminal (``printer``) or on a
virtual clock (``virtual``), with its planner, heaters, motion and seeded faults.

It imports only the link's pure protocol helpers (``drivers.link.protocol``,
``drivers.link.responses``); the link never imports it.
"""
