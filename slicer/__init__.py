"""The implicit slicer: a model in, toolpaths and Marlin G-code out, one layer at a time."""
