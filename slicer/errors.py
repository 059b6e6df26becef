"""The one error the slicer raises for a model it cannot slice."""

from __future__ import annotations


class ModelError(ValueError):
    """A model that cannot be sliced; ``str(err)`` is one specific sentence.

    The text goes verbatim into ``failed/NAME.error.txt``, so it names the
    defect and, where it helps, a number (``not watertight after repair: 223
    open edges``).
    """
