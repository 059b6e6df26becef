"""A field whose lines are as dense as a density field says: the density integrated across them."""

from __future__ import annotations

import numpy as np

from slicer.fields.stress_data import bilinear


class DensityLines:
    """``H(p) = integral of rho along the direction g from the line through c across g``.

    Where ``rho`` varies slowly across ``g``, the level sets of ``H`` are lines across
    ``g`` whose spacing is ``step / rho``: the printed line density follows ``rho``
    itself. (Eq. 14's ``rho * H_lin`` has the gradient ``rho g + H_lin grad rho``:
    far from the centre, where ``H_lin`` is large, the second term thins the lines
    wherever ``rho`` rises towards the centre.)

    ``xs`` (nx,), ``ys`` (ny,) mm and ``rho`` (nx, ny) the density on a grid (data
    frame); ``direction`` (2,) unit vector ``g``; ``origin`` (2,) the point ``c``.
    ``H`` is tabulated on a grid aligned with ``g`` every ``step`` mm (half the
    density grid's finest cell) by the trapezoid rule, and read bilinearly.
    """

    def __init__(self, xs: np.ndarray, ys: np.ndarray, rho: np.ndarray,
                 direction: np.ndarray, origin: np.ndarray) -> None:
        self.g = np.asarray(direction, dtype=float)
        self.n = np.array([-self.g[1], self.g[0]])
        self.origin = np.asarray(origin, dtype=float)
        step = 0.5 * float(min(np.min(np.diff(xs)), np.min(np.diff(ys))))
        corners = np.array([[xs[0], ys[0]], [xs[-1], ys[0]], [xs[0], ys[-1]], [xs[-1], ys[-1]]])
        along = (corners - self.origin) @ self.g
        across = (corners - self.origin) @ self.n
        self.s = np.arange(min(along.min(), 0.0) - step, max(along.max(), 0.0) + 2 * step, step)
        self.t = np.arange(across.min() - step, across.max() + 2 * step, step)
        ss, tt = np.meshgrid(self.s, self.t, indexing="ij")  # (ns, nt)
        px = self.origin[0] + ss * self.g[0] + tt * self.n[0]
        py = self.origin[1] + ss * self.g[1] + tt * self.n[1]
        density = bilinear(xs, ys, rho, px.ravel(), py.ravel()).reshape(ss.shape)
        steps = 0.5 * (density[1:] + density[:-1]) * step
        table = np.concatenate([np.zeros((1, len(self.t))), np.cumsum(steps, axis=0)])
        zero = int(np.argmin(np.abs(self.s)))  # H = 0 on the line through the origin
        self.table = table - table[zero]

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``H`` at points ``x``, ``y`` (n,) mm (data frame) -> (n,) float64."""
        dx = np.ravel(x) - self.origin[0]
        dy = np.ravel(y) - self.origin[1]
        return bilinear(self.s, self.t, self.table, dx * self.g[0] + dy * self.g[1],
                        dx * self.n[0] + dy * self.n[1])
