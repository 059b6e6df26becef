"""Imports every built-in field module so that each registers itself by name."""

from slicer.fields import linear  # noqa: F401
