"""Field coordinate frames: in-layer coordinates centred on the model and rotated."""

from __future__ import annotations

import math

import numpy as np


def centre(bounds: tuple[float, float, float, float]) -> tuple[float, float]:
    """Centre (x, y) mm of a (xmin, ymin, xmax, ymax) box."""
    return 0.5 * (bounds[0] + bounds[2]), 0.5 * (bounds[1] + bounds[3])


def rotated(
    x: np.ndarray, y: np.ndarray, bounds: tuple[float, float, float, float], angle_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates (u, v) mm of points in a frame centred on ``bounds`` and turned by
    ``angle_deg``: ``u`` runs along the angle, ``v`` across it. Same shapes as ``x``, ``y``."""
    cx, cy = centre(bounds)
    t = math.radians(angle_deg)
    dx = np.asarray(x, dtype=float) - cx
    dy = np.asarray(y, dtype=float) - cy
    return dx * math.cos(t) + dy * math.sin(t), -dx * math.sin(t) + dy * math.cos(t)


def unrotated(
    u: np.ndarray, v: np.ndarray, bounds: tuple[float, float, float, float], angle_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`rotated`: frame coordinates (u, v) back to (x, y) mm."""
    cx, cy = centre(bounds)
    t = math.radians(angle_deg)
    u = np.asarray(u, dtype=float)
    v = np.asarray(v, dtype=float)
    return cx + u * math.cos(t) - v * math.sin(t), cy + u * math.sin(t) + v * math.cos(t)
