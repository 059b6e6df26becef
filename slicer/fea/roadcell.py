"""The stiffness of printed roads from their geometry: a periodic cell of crossed roads, solved.

Two layers of parallel roads, the lower along x and the upper along y, each road a
``width`` x ``height`` rectangle, ``fill`` of each layer's area covered (spacing
``width / fill``), perfectly bonded where they touch and repeated without end in
x, y and z. The cell is meshed with the analysis' own trilinear boxes, a uniform
strain is imposed on it with periodic fluctuations, and the average stress
(from the strain energy) gives its homogenised elasticity: first principles
only (the material's E and Poisson's ratio and the roads' shape), nothing fitted.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from slicer.fea.hexmesh import CORNERS, element_matrix

CELLS_ACROSS = 24  # boxes along one period in x and in y
CELLS_PER_LAYER = 3  # boxes through one layer's height
FILLS = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0)  # the table's
# fills, interpolated linearly between: at 0 nothing; up to 0.9 crossed roads apart by a
# gap (0.05 mm at 0.9 for 0.45 mm roads: one pixel of the raster the roads are read on);
# from 0.95 on touching roads, a solid layer with small voids (E * fill): a gap narrower
# than a pixel is not told apart from a notch at the part's edge, and roads laid
# closer than their width squeeze together
TOUCHING = 0.95
# the affine displacement of each unit strain (Voigt order, engineering shear): u = G x
_GRADIENTS = np.zeros((6, 3, 3))
for _k, (_i, _j) in enumerate(((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))):
    _GRADIENTS[_k, _i, _j] += 0.5 if _i != _j else 1.0
    _GRADIENTS[_k, _j, _i] += 0.5 if _i != _j else 0.0


def _band(edges: np.ndarray, width: float) -> np.ndarray:
    """Fraction of each interval between ``edges`` (n+1,) covered by [0, width)."""
    lo, hi = edges[:-1], edges[1:]
    out: NDArray[np.float64] = np.clip(np.minimum(hi, width) - np.maximum(lo, 0.0), 0.0,
                                       None) / (hi - lo)
    return out


def crossed_roads(fill: float, height_over_width: float, poisson: float,
                  across: int = CELLS_ACROSS, per_layer: int = CELLS_PER_LAYER) -> np.ndarray:
    """Homogenised elasticity (6, 6) float64 at E = 1 of crossed layers of roads at
    ``fill`` (0..1] of each layer, roads ``height_over_width`` as high as wide: the
    lower layer's roads along x, the upper's along y (see the module's note)."""
    fill = float(min(max(fill, 1e-3), 1.0))
    spacing = 1.0 / fill  # in road widths
    height = float(height_over_width)
    cell = np.array([spacing / across, spacing / across, height / per_layer])
    shape = np.array([across, across, 2 * per_layer])
    edges = np.arange(across + 1) * cell[0]
    band = _band(edges, 1.0)  # (across,)
    scale = np.zeros(tuple(shape))
    scale[:, :, :per_layer] = band[None, :, None]  # lower layer: roads along x, band in y
    scale[:, :, per_layer:] = band[:, None, None]  # upper layer: roads along y, band in x
    cells = np.argwhere(scale > 0)  # empty boxes carry nothing: left out
    scale = scale[tuple(cells.T)]
    corner = cells[:, None, :] + CORNERS[None, :, :]  # (e, 8, 3) unwrapped
    wrapped = corner % shape
    flat = np.ravel_multi_index(tuple(np.moveaxis(wrapped, -1, 0)), tuple(shape))
    used, nodes = np.unique(flat, return_inverse=True)
    nodes = nodes.reshape(flat.shape)
    dofs = (3 * nodes[:, :, None] + np.arange(3)).reshape(len(cells), 24)
    ke = element_matrix(cell, poisson)
    n = 3 * len(used)
    rows = np.repeat(dofs, 24, axis=1).ravel()
    cols = np.tile(dofs, (1, 24)).ravel()
    data = (scale[:, None, None] * ke[None]).ravel()
    stiffness = sp.csr_matrix((data, (rows, cols)), shape=(n, n))
    positions = corner * cell  # (e, 8, 3)
    affine = np.einsum("kij,enj->keni", _GRADIENTS, positions).reshape(6, len(cells), 24)
    keep = np.arange(3, n)  # node 0 held: the cell's translation
    solver = splu(stiffness[keep][:, keep].tocsc(), permc_spec="MMD_AT_PLUS_A")
    totals = np.empty_like(affine)
    for k in range(6):
        load = -np.einsum("e,ab,eb->ea", scale, ke, affine[k])
        rhs = np.bincount(dofs.ravel(), weights=load.ravel(), minlength=n)
        fluctuation = np.zeros(n)
        fluctuation[keep] = solver.solve(rhs[keep])
        totals[k] = affine[k] + fluctuation[dofs]
    volume = float(np.prod(shape * cell))
    out: NDArray[np.float64] = np.einsum("e,kea,ab,leb->kl", scale, totals, ke, totals) / volume
    return 0.5 * (out + out.T)


@lru_cache(maxsize=16)
def crossed_table(height_over_width: float, poisson: float) -> np.ndarray:
    """:func:`crossed_roads` at each of :data:`FILLS`: (len(FILLS), 6, 6) float64."""
    return np.stack([crossed_roads(f, height_over_width, poisson) for f in FILLS])


def _along_split(crossed: np.ndarray, fill: float) -> np.ndarray:
    """One layer's own elasticity (6, 6), roads along x, from the crossed pair's: the
    pair is the mean of the layer and the layer turned a right angle, so the two
    differ only by how the x and y stiffness is split; the split is the one at which
    a stack of such layers all along x has Young's modulus ``fill * E`` along its
    roads (parallel roads in tension: the rule of mixtures, exact along them)."""
    split = np.zeros((6, 6))
    split[0, 0], split[1, 1] = 1.0, -1.0

    def along(delta: float) -> float:
        return float(1.0 / np.linalg.inv(crossed + delta * split)[0, 0])

    low, high = 0.0, 0.999 * float(crossed[1, 1])
    if along(low) >= fill:
        return crossed
    for _ in range(60):  # bisection: the modulus along x rises with the split
        middle = 0.5 * (low + high)
        if along(middle) < fill:
            low = middle
        else:
            high = middle
    layer = crossed + high * split
    values, vectors = np.linalg.eigh(layer)
    floor = 1e-6 * float(values.max())
    out: NDArray[np.float64] = (vectors * np.maximum(values, floor)) @ vectors.T
    return out


@lru_cache(maxsize=16)
def layer_table(height_over_width: float, poisson: float) -> np.ndarray:
    """One layer of roads along x at each of :data:`FILLS`, as the five harmonics of its
    elasticity turned about z (see :func:`slicer.fea.anisotropic.harmonics`):
    (len(FILLS), 5, 6, 6) float64 at E = 1."""
    from slicer.fea.anisotropic import harmonics, isotropic

    rows = []
    for fill in FILLS:
        if fill <= 0.0:
            rows.append(np.zeros((5, 6, 6)))
            continue
        if fill >= TOUCHING:
            rows.append(harmonics(fill * isotropic(poisson)))
            continue
        rows.append(harmonics(_along_split(crossed_roads(fill, height_over_width, poisson),
                                           fill)))
    return np.stack(rows)
