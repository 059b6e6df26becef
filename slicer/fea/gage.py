"""The tension test's extensometer: where it reads, and its reading as a sum over displacements."""

from __future__ import annotations

import numpy as np

from slicer.fea.loadcase import LoadCase

GAGE_LENGTH = 0.2  # extensometer span as a fraction of the specimen's length, centred
GAGE_BAND = (1.0 / 3.0, 2.0 / 3.0)  # the band across the width it reads, as fractions


def gage_span(lo: np.ndarray, hi: np.ndarray) -> tuple[tuple[float, float], tuple[float, float]]:
    """The extensometer of a specimen along x spanning ``lo`` .. ``hi`` (3,) mm: its ends
    (x0, x1), the middle :data:`GAGE_LENGTH` of the length, and the band (y0, y1) it
    reads, the middle third of the width (the paper's 10 x 20 mm gage on its dogbone)."""
    middle = (float(lo[0]) + float(hi[0])) / 2.0
    span = GAGE_LENGTH * (float(hi[0]) - float(lo[0])) / 2.0
    width = float(hi[1]) - float(lo[1])
    band = (float(lo[1]) + GAGE_BAND[0] * width, float(lo[1]) + GAGE_BAND[1] * width)
    return (middle - span, middle + span), band


def extensometer(
    points: np.ndarray, gage: tuple[float, float], band: tuple[float, float]
) -> tuple[np.ndarray, float]:
    """The extensometer as weights (n, 3) float64 on the nodes' displacements and its
    length, mm: ``sum(weights * displacement)`` is the mean x displacement of the
    nodes in ``band`` (y) on the lattice plane nearest ``gage[1]`` minus that on the
    plane nearest ``gage[0]``, i.e. the gage's extension. ``points`` (n, 3) mm."""
    planes = np.unique(np.round(points[:, 0], 9))
    ends = [float(planes[np.argmin(np.abs(planes - g))]) for g in gage]
    inside = (points[:, 1] >= band[0] - 1e-9) & (points[:, 1] <= band[1] + 1e-9)
    weights = np.zeros((len(points), 3))
    for sign, x in ((-1.0, ends[0]), (1.0, ends[1])):
        chosen = inside & (np.abs(points[:, 0] - x) < 1e-6)
        if not chosen.any():
            raise ValueError(f"no node of the mesh lies on the gage's plane x = {x:g} mm")
        weights[chosen, 0] += sign / chosen.sum()
    return weights, ends[1] - ends[0]


def pulls_along_x(case: LoadCase) -> bool:
    """True when the case is a tension test along x: every force along x (pressures
    such as the jaws' clamping are allowed) and a net pull."""
    forces = [load.vector for load in case.loads if load.vector is not None]
    if not forces or any(abs(v[1]) > 1e-12 or abs(v[2]) > 1e-12 for v in forces):
        return False
    return abs(sum(float(v[0]) for v in forces)) > 0.0
