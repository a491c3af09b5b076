"""Compiled depth below the free surface: the numba counterpart of :mod:`rft_mujoco.physics.terrain`.

The kernels read a terrain in its kernel form, :class:`~rft_mujoco.physics.terrain_spec.TerrainSpec`
(``kind``, ``tp``, ``heights``), built by the one builder :func:`~rft_mujoco.physics.terrain_spec.terrain_spec`
that the warp path shares (re-exported here), and address ``tp`` by its named slots (``tp[ts.TP_REGION]``);
``_depth`` evaluates it at a world point. A terrain without a kernel form gives None and the coupling uses
the numpy reference.
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco import tol
from rft_mujoco.compiled.jit import INLINE, JIT, njit
from rft_mujoco.physics import terrain_spec as ts
from rft_mujoco.physics.deform import DeformableSurface
from rft_mujoco.physics.terrain_spec import DEFORMABLE, FLAT, HEIGHTFIELD, TerrainSpec, terrain_spec

__all__ = ["FLAT", "HEIGHTFIELD", "DEFORMABLE", "TerrainSpec", "terrain_spec", "deformable_heights", "deformed_range",
           "check_gravity", "ABOVE"]


@njit(**INLINE)
def _depth(px, py, pz, g0, g1, g2, kind, tp, heights):
    """Depth (m) of a world point below the terrain: :meth:`FlatSurface.depth`,
    :meth:`HeightfieldSurface.depth`, :meth:`SandRegion.depth`, :meth:`DeformedSurface.depth`, with ``tp`` from
    :func:`terrain_spec`."""
    if tp[ts.TP_REGION] != 0.0:  # bounded region
        if not (px >= tp[ts.TP_REGION_X0] and px <= tp[ts.TP_REGION_X1] and py >= tp[ts.TP_REGION_Y0]
                and py <= tp[ts.TP_REGION_Y1]):
            return -np.inf
    if kind == FLAT:
        return tp[ts.TP_HEIGHT] + (px * g0 + py * g1 + pz * g2)
    if kind == DEFORMABLE:
        return _deformed_depth(px, py, pz, tp, heights)
    nrow = heights.shape[0]
    ncol = heights.shape[1]
    u = (px - tp[ts.TP_HF_X0]) / (tp[ts.TP_HF_X1] - tp[ts.TP_HF_X0]) * (ncol - 1)
    w = (py - tp[ts.TP_HF_Y0]) / (tp[ts.TP_HF_Y1] - tp[ts.TP_HF_Y0]) * (nrow - 1)
    if u != u or w != w:
        return -np.inf
    inside = u >= 0 and u <= ncol - 1 and w >= 0 and w <= nrow - 1
    if tp[ts.TP_HF_OUTSIDE_NONE] != 0.0 and not inside:  # outside == "none"
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


@njit(**INLINE)
def _deformed_depth(px, py, pz, tp, grid):
    """Effective depth (m) of a world point below a deformed surface: the numbers of
    :meth:`rft_mujoco.physics.deform.DeformedSurface.depth` (bilinear height and preload, in the same order
    of operations, then :func:`rft_mujoco.physics.deform.effective_depth`). ``grid`` (2 ny, nx): heights (m)
    in rows ``0..ny-1``, preload (m) in rows ``ny..2 ny-1``; ``tp`` of :func:`terrain_spec` (the initial height,
    the grid's origin and spacing, ``reload_ratio``)."""
    ny = grid.shape[0] // 2
    nx = grid.shape[1]
    u = (px - tp[ts.TP_GRID_X0]) / tp[ts.TP_GRID_DX]
    w = (py - tp[ts.TP_GRID_Y0]) / tp[ts.TP_GRID_DY]
    if not (u >= 0 and u <= nx - 1 and w >= 0 and w <= ny - 1):
        return tp[ts.TP_HEIGHT] - pz                 # outside the grid: the initial surface, no memory
    i0 = min(int(math.floor(w)), max(ny - 2, 0))
    j0 = min(int(math.floor(u)), max(nx - 2, 0))
    i1 = min(i0 + 1, ny - 1)
    j1 = min(j0 + 1, nx - 1)
    fu = u - j0
    fw = w - i0
    h = ((1 - fw) * ((1 - fu) * grid[i0, j0] + fu * grid[i0, j1])
         + fw * ((1 - fu) * grid[i1, j0] + fu * grid[i1, j1]))
    q00, q01, q10, q11 = grid[ny + i0, j0], grid[ny + i0, j1], grid[ny + i1, j0], grid[ny + i1, j1]
    if q00 == 0.0 and q01 == 0.0 and q10 == 0.0 and q11 == 0.0:
        return h - pz                                # virgin sand (no preload): the depth itself, as below
    q = ((1 - fw) * ((1 - fu) * grid[ny + i0, j0] + fu * grid[ny + i0, j1])
         + fw * ((1 - fu) * grid[ny + i1, j0] + fu * grid[ny + i1, j1]))
    d = h - pz
    ratio = tp[ts.TP_RELOAD_RATIO]
    e = q / ratio
    if d <= 0.0:
        return d
    if d <= e:
        return ratio * d
    return q + d - e


ABOVE = 1e-12
"""m: a cluster whose lowest point is this much above the deformed surface's highest node around it is above
the sand, and one whose highest point is this much below the lowest node under it is under it (bilinear
heights may leave their nodes' range by round-off)."""


@njit(**JIT)
def deformed_range(px, py, radius, tp, grid):
    """(lowest, highest) m of the nodes of a deformed surface (``grid`` of :func:`_deformed_depth`) within
    ``radius`` m of (``px``, ``py``) in x and y, one node around included, and of the initial height (``tp``'s)
    where that square leaves the grid: the surface under a sphere of that radius is within this range
    (bilinear heights are within their nodes' range, to round-off), so an element of the sphere above the
    highest is above the sand, and one below the lowest under it."""
    ny = grid.shape[0] // 2
    nx = grid.shape[1]
    x0, dx, y0, dy = tp[ts.TP_GRID_X0], tp[ts.TP_GRID_DX], tp[ts.TP_GRID_Y0], tp[ts.TP_GRID_DY]
    u0 = math.floor((px - radius - x0) / dx)
    u1 = math.ceil((px + radius - x0) / dx)
    w0 = math.floor((py - radius - y0) / dy)
    w1 = math.ceil((py + radius - y0) / dy)
    lo, hi = np.inf, -np.inf
    if not (u0 >= 0 and w0 >= 0 and u1 <= nx - 1 and w1 <= ny - 1):
        lo = hi = tp[ts.TP_HEIGHT]                   # (outside the grid: the initial surface)
    for i in range(max(int(w0), 0), min(int(w1), ny - 1) + 1):
        for j in range(max(int(u0), 0), min(int(u1), nx - 1) + 1):
            lo = min(lo, grid[i, j])
            hi = max(hi, grid[i, j])
    return lo, hi


def deformable_heights(grid: DeformableSurface) -> np.ndarray:
    """A fresh ``(2 ny, nx)`` array of a deformable surface's state for the kernels: the initial heights (m)
    over a zero preload (m), its :class:`TerrainSpec`'s heights. The coupling keeps one per MjData;
    ``heights[:ny]`` and ``heights[ny:]`` are the ``heights`` and ``preload`` of its
    :class:`~rft_mujoco.physics.deform.DeformedSurface` (views)."""
    return terrain_spec(grid).heights


def check_gravity(terrain, spec: TerrainSpec, g_hat: np.ndarray) -> None:
    """The numpy terrains' own check: heightfields and bounded regions need gravity along -z (raises the
    terrain's ValueError)."""
    if spec.needs_vertical_gravity and g_hat[2] > -1.0 + tol.VERTICAL_GRAVITY_TOL:
        terrain.depth(np.zeros((1, 3)), g_hat)
