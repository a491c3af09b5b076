"""The terrains' kernel form, by name: terrain kinds, the named slots of the parameter vector, the
:class:`Terrain` protocol and the one builder :func:`terrain_spec` (pure numpy).

The compiled kernels (:mod:`rft_mujoco.compiled.terrain`) and the warp kernels (:mod:`rft_mujoco.warp.law`)
evaluate a terrain from three things: its kind (:class:`TerrainKind`), a float vector of parameters (``tp``,
:data:`PARAMS` slots, the same layout for every kind and for both backends) and a 2-D array of heights.
Every terrain class writes its own :class:`TerrainSpec` in its ``kernel_spec()`` method, so that a new terrain
kind writes its kernel form in one place; :func:`terrain_spec` asks the terrain for it and returns None for a
terrain that has none (the coupling then evaluates it with the numpy reference).

The slot constants are module-level ints: numba and warp freeze them into the compiled code as constants, so
``tp[ts.TP_REGION]`` (``from rft_mujoco.physics import terrain_spec as ts``) costs what ``tp[7]`` costs.
Imports nothing of the package (the terrains import it).
"""

from __future__ import annotations

import enum
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np


class TerrainKind(enum.IntEnum):
    """What the kernels evaluate: a flat surface (any gravity direction), a bilinear heightfield (gravity along
    -z), a deformable surface's grid with its loading memory (gravity along -z)."""

    FLAT = 0
    HEIGHTFIELD = 1
    DEFORMABLE = 2


FLAT = int(TerrainKind.FLAT)
"""The kinds as plain ints, for the kernels (numba types an IntEnum member as a type of its own)."""
HEIGHTFIELD = int(TerrainKind.HEIGHTFIELD)
DEFORMABLE = int(TerrainKind.DEFORMABLE)

PARAMS = ("height", "max_height", "hf_x0", "hf_x1", "hf_y0", "hf_y1", "hf_outside_none", "region", "region_x0",
          "region_x1", "region_y0", "region_y1", "grid_x0", "grid_dx", "grid_y0", "grid_dy", "reload_ratio",
          "reload_sinkage", "reload_decay", "compaction", "berm_cells", "relax_cells", "relax", "slope",
          "cover_grow", "update_interval")
"""Slots of a terrain's parameter vector ``tp`` (every kind, both backends; unused slots 0):

* ``height`` (m): a flat surface's height; a deformable surface's initial (flat) height.
* ``max_height`` (m): an upper bound of the surface height at attach (the terrain's ``max_height``; for a
  deformable surface its initial height: the coupling keeps each MjData's own bound).
* ``hf_x0, hf_x1, hf_y0, hf_y1`` (m): the world x and y ranges of a heightfield's columns and rows;
  ``hf_outside_none``: 1 where there is no sand outside the grid (``outside="none"``), 0 for ``"edge"``.
* ``region``: 1 for a :class:`~rft_mujoco.physics.terrain.SandRegion` (sand only inside the rectangle
  ``region_x0 <= x <= region_x1``, ``region_y0 <= y <= region_y1``, m), 0 otherwise.
* deformable surface (:class:`~rft_mujoco.physics.deform.DeformableSurface`): ``grid_x0, grid_dx, grid_y0,
  grid_dy`` (m) the grid's origin and node spacing along x and y; ``reload_ratio``, ``reload_sinkage``,
  ``reload_decay``, ``compaction`` (dimensionless, the surface's); ``berm_cells`` the berm's half-width in
  nodes (:func:`~rft_mujoco.physics.deform.berm_nodes`'s r), ``relax_cells`` the slope flow's margin in nodes
  (``relax``'s r), ``relax`` 1 when the slope flow is on, ``slope`` ``tan(repose_angle)``, ``cover_grow``
  (cells, :data:`rft_mujoco.physics.deform.COVER_GROW`), ``update_interval`` (s).
"""

(TP_HEIGHT, TP_MAX_HEIGHT, TP_HF_X0, TP_HF_X1, TP_HF_Y0, TP_HF_Y1, TP_HF_OUTSIDE_NONE, TP_REGION, TP_REGION_X0,
 TP_REGION_X1, TP_REGION_Y0, TP_REGION_Y1, TP_GRID_X0, TP_GRID_DX, TP_GRID_Y0, TP_GRID_DY, TP_RELOAD_RATIO,
 TP_RELOAD_SINKAGE, TP_RELOAD_DECAY, TP_COMPACTION, TP_BERM_CELLS, TP_RELAX_CELLS, TP_RELAX, TP_SLOPE,
 TP_COVER_GROW, TP_UPDATE_INTERVAL) = range(len(PARAMS))
N_PARAMS = len(PARAMS)
"""Length of ``tp``."""

NO_HEIGHTS = np.zeros((2, 2))
NO_HEIGHTS.setflags(write=False)
"""The heights of a terrain without a grid (flat): a (2, 2) array of zeros, read-only (the kernels take a 2-D
array; :func:`terrain_spec` returns a writeable copy)."""


class TerrainSpec(NamedTuple):
    """A terrain in the form the compiled and warp kernels read (float64; warp casts to float32)."""

    kind: int
    """A :class:`TerrainKind` value (a plain int: the kernels take it as an argument)."""
    params: np.ndarray
    """``tp``: (:data:`N_PARAMS`,) float64, the slots of :data:`PARAMS` (m unless said otherwise there)."""
    heights: np.ndarray
    """(nrow, ncol) float64 m: a heightfield's heights (row along y, column along x); for a deformable surface
    the initial state, (2 ny, nx): heights over a zero preload (each MjData takes its own copy); for a flat
    surface :data:`NO_HEIGHTS`."""

    @property
    def needs_vertical_gravity(self) -> bool:
        """Whether the terrain is laid out in the world xy-plane (every kind but an unbounded flat surface)."""
        return self.kind != FLAT or self.params[TP_REGION] != 0.0


def new_params(**slots: float) -> np.ndarray:
    """A fresh ``tp`` (:data:`N_PARAMS`,) float64: the given slots (by their :data:`PARAMS` names), 0 elsewhere."""
    tp = np.zeros(N_PARAMS)
    for name, value in slots.items():
        if name not in PARAMS:
            raise ValueError(f"no terrain parameter slot {name!r}; the slots are {PARAMS}")
        tp[PARAMS.index(name)] = value
    return tp


@runtime_checkable
class Terrain(Protocol):
    """A free surface of the sand: what the coupling, the compiled and the warp paths ask of a terrain.

    Implemented by :class:`~rft_mujoco.physics.terrain.FlatSurface`,
    :class:`~rft_mujoco.physics.terrain.HeightfieldSurface`, :class:`~rft_mujoco.physics.terrain.SandRegion` and
    :class:`~rft_mujoco.physics.deform.DeformableSurface`. A user's terrain needs only ``depth`` and
    ``max_height`` (the coupling evaluates it in numpy); ``kernel_spec`` returning a :class:`TerrainSpec` lets the
    kernels evaluate it (its kind must be one they know).
    """

    @property
    def max_height(self) -> float:
        """m, an upper bound of the surface height (the broadphase's)."""

    def depth(self, points: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
        """(n,) m, depth of ``points`` (n, 3) world m below the surface along the unit gravity ``g_hat`` (3,)
        (> 0 below, ``-inf`` where there is no sand)."""

    def kernel_spec(self) -> TerrainSpec | None:
        """The terrain's :class:`TerrainSpec`, or None when the kernels cannot evaluate it."""


def _owner(cls: type, name: str) -> type | None:
    return next((c for c in cls.__mro__ if name in vars(c)), None)


def terrain_spec(terrain) -> TerrainSpec | None:
    """The kernel form of ``terrain`` (its ``kernel_spec()``), or None for a terrain the kernels do not know:
    one without ``kernel_spec``, one whose ``kernel_spec`` returns None, and one whose class overrides ``depth``
    below the class that wrote its ``kernel_spec`` (a subclass of a FlatSurface with its own depth: the
    spec would not be its depth). The caller falls back to the numpy reference."""
    cls = type(terrain)
    spec_owner, depth_owner = _owner(cls, "kernel_spec"), _owner(cls, "depth")
    if spec_owner is None or depth_owner is None or not issubclass(spec_owner, depth_owner):
        return None
    spec = terrain.kernel_spec()
    if spec is None:
        return None
    if not isinstance(spec, TerrainSpec) or spec.kind not in set(TerrainKind) \
            or np.shape(spec.params) != (N_PARAMS,) or np.ndim(spec.heights) != 2:
        raise ValueError(f"{cls.__name__}.kernel_spec() must return None or a TerrainSpec (kind in "
                         f"{[int(k) for k in TerrainKind]}, params ({N_PARAMS},), heights 2-D), got {spec!r:.200}")
    # fresh, writeable C arrays: numba types a read-only array (a HeightfieldSurface's heights) as another type
    return TerrainSpec(int(spec.kind), np.array(spec.params, dtype=np.float64, order="C"),
                       np.array(spec.heights, dtype=np.float64, order="C"))
