"""Infill fields: scalar fields over a layer whose level sets become infill toolpaths.

Each field is a strategy registered by name (the `infill.field` setting); see
:mod:`slicer.fields.base` for the interface.
"""

from slicer.fields.base import FIELDS, InfillField, LayerContext, get_field, register

__all__ = ["FIELDS", "InfillField", "LayerContext", "get_field", "register"]
