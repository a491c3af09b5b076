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
from rft_mujoco.compiled.jit import INLINE, JIT, njit
from rft_mujoco.physics.deform import COVER_GROW, DeformableSurface
from rft_mujoco.physics.terrain import FlatSurface, HeightfieldSurface, SandRegion

FLAT = 0
"""Terrain kind of :func:`terrain_spec`: a flat surface (any gravity direction)."""
HEIGHTFIELD = 1
"""Terrain kind of :func:`terrain_spec`: a bilinear heightfield (gravity along -z)."""
DEFORMABLE = 2
"""Terrain kind of :func:`terrain_spec`: a deformable surface's grid with its loading memory (gravity along -z)."""


@njit(**INLINE)
def _depth(px, py, pz, g0, g1, g2, kind, tp, heights):
    """Depth (m) of a world point below the terrain: :meth:`FlatSurface.depth`,
    :meth:`HeightfieldSurface.depth`, :meth:`SandRegion.depth`, with ``tp`` from :func:`terrain_spec`."""
    if tp[6] != 0.0:  # bounded region
        if not (px >= tp[7] and px <= tp[8] and py >= tp[9] and py <= tp[10]):
            return -np.inf
    if kind == FLAT:
        return tp[0] + (px * g0 + py * g1 + pz * g2)
    if kind == DEFORMABLE:
        return _deformed_depth(px, py, pz, tp, heights)
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


@njit(**INLINE)
def _deformed_depth(px, py, pz, tp, grid):
    """Effective depth (m) of a world point below a deformed surface: the numbers of
    :meth:`rft_mujoco.physics.deform.DeformedSurface.depth` (bilinear height and preload, in the same order
    of operations, then :func:`rft_mujoco.physics.deform.effective_depth`). ``grid`` (2 ny, nx): heights (m)
    in rows ``0..ny-1``, preload (m) in rows ``ny..2 ny-1``; ``tp`` of :func:`terrain_spec`: ``[initial
    height, x origin, x spacing, y origin, y spacing, 0, 0, 0, 0, 0, 0, reload_ratio]``."""
    ny = grid.shape[0] // 2
    nx = grid.shape[1]
    u = (px - tp[1]) / tp[2]
    w = (py - tp[3]) / tp[4]
    if not (u >= 0 and u <= nx - 1 and w >= 0 and w <= ny - 1):
        return tp[0] - pz                            # outside the grid: the initial surface, no memory
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
    ratio = tp[11]
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
    ``radius`` m of (``px``, ``py``) in x and y, one node around included, and of the initial height ``tp[0]``
    where that square leaves the grid: the surface under a sphere of that radius is within this range
    (bilinear heights are within their nodes' range, to round-off), so an element of the sphere above the
    highest is above the sand, and one below the lowest under it."""
    ny = grid.shape[0] // 2
    nx = grid.shape[1]
    u0 = math.floor((px - radius - tp[1]) / tp[2])
    u1 = math.ceil((px + radius - tp[1]) / tp[2])
    w0 = math.floor((py - radius - tp[3]) / tp[4])
    w1 = math.ceil((py + radius - tp[3]) / tp[4])
    lo, hi = np.inf, -np.inf
    if not (u0 >= 0 and w0 >= 0 and u1 <= nx - 1 and w1 <= ny - 1):
        lo = hi = tp[0]                              # (outside the grid: the initial surface)
    for i in range(max(int(w0), 0), min(int(w1), ny - 1) + 1):
        for j in range(max(int(u0), 0), min(int(u1), nx - 1) + 1):
            lo = min(lo, grid[i, j])
            hi = max(hi, grid[i, j])
    return lo, hi


_NO_HEIGHTS = np.zeros((2, 2))


def deformable_heights(grid: DeformableSurface) -> np.ndarray:
    """A fresh ``(2 ny, nx)`` array of a deformable surface's state for the kernels: the initial heights (m)
    over a zero preload (m). The coupling keeps one per MjData; ``heights[:ny]`` and ``heights[ny:]`` are the
    ``heights`` and ``preload`` of its :class:`~rft_mujoco.physics.deform.DeformedSurface` (views)."""
    ny, nx = grid.shape
    out = np.zeros((2 * ny, nx))
    out[:ny] = grid.height
    return out


def terrain_spec(terrain) -> tuple[int, np.ndarray, np.ndarray] | None:
    """``(kind, params (11,) float, heights (nrow, ncol) float)`` for the compiled depth, or None for a
    terrain the compiled kernel does not know (the caller falls back to numpy).

    params: ``[flat height, x0, x1, y0, y1, outside_none, is_region, rx0, rx1, ry0, ry1]``; for a
    :class:`DeformableSurface` (kind :data:`DEFORMABLE`) ``[initial height, x origin, x spacing, y origin,
    y spacing, 0, 0, 0, 0, 0, 0, reload_ratio, ...]`` (:data:`rft_mujoco.compiled.deform.TP`) and the initial
    state's heights (each MjData has its own).
    """
    if type(terrain) is DeformableSurface:
        tp = np.zeros(21)                            # (rft_mujoco.compiled.deform.TP)
        tp[0] = terrain.height
        tp[1:5] = (terrain.origin[0], terrain.spacing[0], terrain.origin[1], terrain.spacing[1])
        tp[11:15] = (terrain.reload_ratio, terrain.reload_sinkage, terrain.reload_decay, terrain.compaction)
        berm = max(1, int(math.floor(terrain.berm_width / min(terrain.spacing) + tol.ROUND_RTOL)))
        tp[15:18] = (berm, berm + 2, terrain.repose_angle is not None)
        tp[18] = math.tan(math.radians(terrain.repose_angle)) if terrain.repose_angle is not None else 0.0
        tp[19:21] = (COVER_GROW, terrain.update_interval)
        return DEFORMABLE, tp, deformable_heights(terrain)
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
