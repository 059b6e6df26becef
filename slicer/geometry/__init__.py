"""Geometry helpers with no slicing policy: shapely array helpers, convex insets in numpy,
RGBA rasters.
"""
