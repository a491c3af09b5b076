"""Compiled depth below the free surface: the numba counterpart of :mod:`rft_mujoco.physics.terrain`.

:func:`terrain_spec` turns a :class:`~rft_mujoco.physics.terrain.FlatSurface`,
:class:`~rft_mujoco.physics.terrain.HeightfieldSurface` or :class:`~rft_mujoco.physics.terrain.SandRegion`
into ``(kind, params, heights)`` arrays the kernels read; ``_depth`` evaluates it at a world point. Any
other terrain gives None and the coupling uses the numpy reference.
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco import tol
from rft_mujoco.compiled.jit import JIT, njit
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion

FLAT = 0
"""Terrain kind of :func:`terrain_spec`: a flat surface (any gravity direction)."""
HEIGHTFIELD = 1
"""Terrain kind of :func:`terrain_spec`: a bilinear heightfield (gravity along -z)."""


@njit(**JIT)
def _depth(px, py, pz, g0, g1, g2, kind, tp, heights):
    """Depth (m) of a world point below the terrain: :meth:`FlatSurface.depth`,
    :meth:`HeightfieldSurface.depth`, :meth:`SandRegion.depth`, with ``tp`` from :func:`terrain_spec`."""
    if tp[6] != 0.0:  # bounded region
        if not (px >= tp[7] and px <= tp[8] and py >= tp[9] and py <= tp[10]):
            return -np.inf
    if kind == FLAT:
        return tp[0] + (px * g0 + py * g1 + pz * g2)
    nrow = heights.shape[0]
    ncol = heights.shape[1]
    u = (px - tp[1]) / (tp[2] - tp[1]) * (ncol - 1)
    w = (py - tp[3]) / (tp[4] - tp[3]) * (nrow - 1)
    if u != u or w != w:
        return -np.inf
    inside = u >= 0 and u <= ncol - 1 and w >= 0 and w <= nrow - 1
    if tp[5] != 0.0 and not inside:  # outside == "none"
        return -np.inf
    u = min(max(u, 0.0), ncol - 1.0)
    w = min(max(w, 0.0), nrow - 1.0)
    i0 = min(int(math.floor(w)), nrow - 2)
    j0 = min(int(math.floor(u)), ncol - 2)
    fu = u - j0
    fw = w - i0
    z = ((1 - fw) * ((1 - fu) * heights[i0, j0] + fu * heights[i0, j0 + 1])
         + fw * ((1 - fu) * heights[i0 + 1, j0] + fu * heights[i0 + 1, j0 + 1]))
    return z - pz


_NO_HEIGHTS = np.zeros((2, 2))


def terrain_spec(terrain) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(kind, params (11,) float, heights (nrow, ncol) float)`` for the compiled depth, or None for a
    terrain the compiled kernel does not know (the caller falls back to numpy).

    params: ``[flat height, x0, x1, y0, y1, outside_none, is_region, rx0, rx1, ry0, ry1]``.
    """
    tp = np.zeros(11)
    inner = terrain
    if type(terrain) is SandRegion:
        tp[6] = 1.0
        tp[7:11] = (*terrain.x_range, *terrain.y_range)
        inner = terrain.surface
    if type(inner) is FlatSurface:
        tp[0] = inner.height
        return FLAT, tp, _NO_HEIGHTS
    if type(inner) is HeightfieldSurface:
        tp[1:5] = (*inner.x_range, *inner.y_range)
        tp[5] = 1.0 if inner.outside == "none" else 0.0
        return HEIGHTFIELD, tp, np.array(inner.heights, dtype=np.float64, order="C")
    return None


def check_gravity(terrain, spec, g_hat: np.ndarray) -> None:
    """The numpy terrains' own check: heightfields and bounded regions need gravity along -z (raises the
    terrain's ValueError)."""
    kind, tp, _ = spec
    if (kind != FLAT or tp[6] != 0.0) and g_hat[2] > -1.0 + tol.VERTICAL_GRAVITY_TOL:
        terrain.depth(np.zeros((1, 3)), g_hat)
