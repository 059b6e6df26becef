"""Toolpaths of a layer: islands and their walls, skins, infill and support paths, their
order, travel detours and arc fitting.
"""
