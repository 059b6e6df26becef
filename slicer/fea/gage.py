"""The tension test's extensometer: where it reads, and its reading as a sum over displacements."""

from __future__ import annotations

import numpy as np

from slicer.fea.loadcase import LoadCase

GAGE_MM = 20.0  # the default extensometer span, mm: the paper's 20 mm gage, centred
GAGE_BAND = (1.0 / 3.0, 2.0 / 3.0)  # the band across the width it reads, as fractions
LONGER = 2.5  # the second span, as a multiple of the named one


def gage_length(case: LoadCase, lo: np.ndarray, hi: np.ndarray) -> float:
    """The extensometer's span, mm: the case's ``[test] gage_length_mm``, else
    :data:`GAGE_MM`; never more than 90 % of the specimen's length (``lo``..``hi``)."""
    length = float(hi[0]) - float(lo[0])
    return min(case.gage_length_mm or GAGE_MM, 0.9 * length)


def gage_span(lo: np.ndarray, hi: np.ndarray, length: float
              ) -> tuple[tuple[float, float], tuple[float, float]]:
    """The extensometer of a specimen along x spanning ``lo`` .. ``hi`` (3,) mm: its ends
    (x0, x1), ``length`` mm centred on the specimen, and the band (y0, y1) it reads,
    the middle third of the width (the paper's 10 x 20 mm gage on its dogbone)."""
    middle = (float(lo[0]) + float(hi[0])) / 2.0
    span = length / 2.0
    width = float(hi[1]) - float(lo[1])
    band = (float(lo[1]) + GAGE_BAND[0] * width, float(lo[1]) + GAGE_BAND[1] * width)
    return (middle - span, middle + span), band


def between_grips(case: LoadCase, lo: np.ndarray, hi: np.ndarray) -> float:
    """The free length between the held faces and the pulled ones along x, mm (the
    specimen's length when the regions do not say)."""
    held = [float(r.box[1][0]) for r in case.fixed if float(r.box[1][0]) < float(hi[0])]
    pulled = [float(load.region.box[0][0]) for load in case.loads
              if load.vector is not None and float(load.region.box[0][0]) > float(lo[0])]
    start = max(held) if held else float(lo[0])
    end = min(pulled) if pulled else float(hi[0])
    return end - start if end > start else float(hi[0]) - float(lo[0])


def spans(case: LoadCase, lo: np.ndarray, hi: np.ndarray) -> tuple[float, ...]:
    """The extensometer spans a report reads, mm: the named one (:func:`gage_length`),
    :data:`LONGER` times it, and the whole free length between the grips (each
    kept only when longer than the one before and within the grips)."""
    named = gage_length(case, lo, hi)
    free = between_grips(case, lo, hi)
    out = [named]
    for span in (LONGER * named, free):
        if out[-1] * 1.05 < span <= free + 1e-9:
            out.append(span)
    return tuple(out)


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
