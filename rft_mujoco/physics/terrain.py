"""Free surfaces of the sand: height of the surface and depth of points below it (pure numpy).

Depth is measured along gravity: ``depth = h_surface(x, y) - height(p)`` with ``height = p . (-g_hat)``.
Flat surfaces work for any gravity direction; heightfields and bounded regions are laid out in the world
xy-plane and need gravity along -z.

Every terrain is a frozen dataclass with
``depth(points_world (n, 3) float, g_hat (3,) float) -> (n,) float`` in m (> 0 below the surface,
``-inf`` where there is no sand), ``max_height`` (m, an upper bound of the surface height used by the
broadphase) and ``kernel_spec()``, its form for the compiled and warp kernels: they satisfy the
:class:`Terrain` protocol (:mod:`rft_mujoco.physics.terrain_spec`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rft_mujoco import tol
from rft_mujoco.physics import terrain_spec as ts
from rft_mujoco.physics.terrain_spec import Terrain, TerrainSpec

NO_SAND = -np.inf
"""Depth returned where there is no sand (outside a bounded region)."""


def _check_vertical_gravity(g_hat: np.ndarray, what: str) -> None:
    if g_hat[2] > -1.0 + tol.VERTICAL_GRAVITY_TOL:
        raise ValueError(f"{what} needs gravity along -z (heights are world z), got gravity direction "
                         f"{np.round(g_hat, 6).tolist()}; use a FlatSurface for tilted gravity")


@dataclasses.dataclass(frozen=True)
class FlatSurface:
    """A flat, unbounded free surface at ``height`` m (measured against gravity)."""

    height: float = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.height):
            raise ValueError(f"surface height must be finite (m), got {self.height!r}")

    @property
    def max_height(self) -> float:
        return float(self.height)

    def depth(self, points: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
        return self.height + points @ g_hat

    def kernel_spec(self) -> TerrainSpec:
        """Kind FLAT; ``height`` and ``max_height`` the surface's height."""
        return TerrainSpec(ts.FLAT, ts.new_params(height=self.height, max_height=self.height), ts.NO_HEIGHTS)


@dataclasses.dataclass(frozen=True, eq=False)
class HeightfieldSurface:
    """A sand surface given by a grid of heights, bilinearly interpolated (like a MuJoCo heightfield).

    Attributes:
        heights: (nrow, ncol) float, surface heights in m (world z); row index along y, column along x,
            as MuJoCo lays out ``hfield_data``.
        x_range: (xmin, xmax) in m, world x covered by the columns.
        y_range: (ymin, ymax) in m, world y covered by the rows.
        outside: what lies outside the grid: ``"edge"`` extends the border heights, ``"none"`` means no
            sand there.
    """

    heights: np.ndarray
    x_range: tuple[float, float]
    y_range: tuple[float, float]
    outside: str = "edge"

    def __post_init__(self) -> None:
        h = np.asarray(self.heights, dtype=float)
        if h.ndim != 2 or min(h.shape) < 2 or not np.all(np.isfinite(h)):
            raise ValueError(f"heights must be a finite (nrow >= 2, ncol >= 2) array, got shape {h.shape}")
        for name, (lo, hi) in (("x_range", self.x_range), ("y_range", self.y_range)):
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise ValueError(f"{name} must be (low, high) with high > low in m, got {(lo, hi)}")
        if self.outside not in ("edge", "none"):
            raise ValueError(f"outside must be 'edge' or 'none', got {self.outside!r}")
        h.setflags(write=False)
        object.__setattr__(self, "heights", h)

    @classmethod
    def from_model(cls, model, geom: int | str, outside: str = "edge") -> "HeightfieldSurface":
        """The heightfield of a MuJoCo ``hfield`` geom (axis-aligned: the geom may not be rotated)."""
        import mujoco

        gid = geom if isinstance(geom, int) else mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, geom)
        if gid < 0 or gid >= model.ngeom:
            raise ValueError(f"no geom named {geom!r} in the model")
        if model.geom_type[gid] != mujoco.mjtGeom.mjGEOM_HFIELD:
            raise ValueError(f"geom {geom!r} is not an hfield geom (type {model.geom_type[gid]})")
        if model.geom_bodyid[gid] != 0:
            raise ValueError(f"hfield geom {geom!r} must belong to the world body to serve as terrain")
        if not np.allclose(model.geom_quat[gid], [1, 0, 0, 0]):
            raise ValueError(f"hfield geom {geom!r} is rotated; only axis-aligned heightfields are supported")
        hid = model.geom_dataid[gid]
        nrow, ncol = int(model.hfield_nrow[hid]), int(model.hfield_ncol[hid])
        adr = int(model.hfield_adr[hid])
        rx, ry, top, _base = model.hfield_size[hid]
        data = np.asarray(model.hfield_data[adr:adr + nrow * ncol], dtype=float).reshape(nrow, ncol)
        px, py, pz = model.geom_pos[gid]
        return cls(pz + top * data, (px - rx, px + rx), (py - ry, py + ry), outside)

    @property
    def max_height(self) -> float:
        return float(self.heights.max())

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface height (m) at world (x, y); NaN outside the grid when ``outside == "none"``."""
        nrow, ncol = self.heights.shape
        u = (np.asarray(x, float) - self.x_range[0]) / (self.x_range[1] - self.x_range[0]) * (ncol - 1)
        w = (np.asarray(y, float) - self.y_range[0]) / (self.y_range[1] - self.y_range[0]) * (nrow - 1)
        inside = (u >= 0) & (u <= ncol - 1) & (w >= 0) & (w <= nrow - 1)
        u = np.clip(u, 0, ncol - 1)
        w = np.clip(w, 0, nrow - 1)
        i0 = np.minimum(np.floor(w).astype(int), nrow - 2)
        j0 = np.minimum(np.floor(u).astype(int), ncol - 2)
        fu, fw = u - j0, w - i0
        h = self.heights
        z = ((1 - fw) * ((1 - fu) * h[i0, j0] + fu * h[i0, j0 + 1])
             + fw * ((1 - fu) * h[i0 + 1, j0] + fu * h[i0 + 1, j0 + 1]))
        if self.outside == "none":
            z = np.where(inside, z, np.nan)
        return z

    def depth(self, points: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
        _check_vertical_gravity(g_hat, "a heightfield surface")
        z = self.height_at(points[:, 0], points[:, 1])
        d = z - points[:, 2]
        return np.where(np.isnan(d), NO_SAND, d)

    def kernel_spec(self) -> TerrainSpec:
        """Kind HEIGHTFIELD: the grid's ranges and ``outside`` in ``tp``, the heights (m) as they are."""
        tp = ts.new_params(max_height=self.max_height, hf_x0=self.x_range[0], hf_x1=self.x_range[1],
                           hf_y0=self.y_range[0], hf_y1=self.y_range[1],
                           hf_outside_none=1.0 if self.outside == "none" else 0.0)
        return TerrainSpec(ts.HEIGHTFIELD, tp, self.heights)


@dataclasses.dataclass(frozen=True)
class SandRegion:
    """Sand only inside an axis-aligned rectangle of the world xy-plane; no sand (rigid ground, if the
    scene has one) elsewhere.

    Attributes:
        surface: the free surface inside the region (flat or heightfield).
        x_range, y_range: (low, high) bounds in m.
    """

    surface: FlatSurface | HeightfieldSurface
    x_range: tuple[float, float]
    y_range: tuple[float, float]

    def __post_init__(self) -> None:
        for name, (lo, hi) in (("x_range", self.x_range), ("y_range", self.y_range)):
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise ValueError(f"{name} must be (low, high) with high > low in m, got {(lo, hi)}")

    @property
    def max_height(self) -> float:
        return self.surface.max_height

    def depth(self, points: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
        _check_vertical_gravity(g_hat, "a bounded sand region")
        d = self.surface.depth(points, g_hat)
        inside = ((points[:, 0] >= self.x_range[0]) & (points[:, 0] <= self.x_range[1])
                  & (points[:, 1] >= self.y_range[0]) & (points[:, 1] <= self.y_range[1]))
        return np.where(inside, d, NO_SAND)

    def kernel_spec(self) -> TerrainSpec | None:
        """The inner surface's spec with the ``region`` slots set (None when the kernels do not know the
        inner surface as a region's: a deformable surface, a region)."""
        inner = ts.terrain_spec(self.surface)
        if inner is None or inner.kind == ts.DEFORMABLE or inner.params[ts.TP_REGION] != 0.0:
            return None                      # (a region of a region: not a kernel form)
        tp = inner.params.copy()
        tp[ts.TP_REGION] = 1.0
        tp[[ts.TP_REGION_X0, ts.TP_REGION_X1, ts.TP_REGION_Y0, ts.TP_REGION_Y1]] = (*self.x_range, *self.y_range)
        return TerrainSpec(inner.kind, tp, inner.heights)


def as_terrain(surface) -> Terrain:
    """A terrain from a height in m (flat) or a terrain object (a :class:`Terrain`, or any object with
    ``depth(points, g_hat)`` and ``max_height``: without a ``kernel_spec`` the coupling evaluates it in numpy)."""
    if isinstance(surface, Terrain):
        return surface
    if isinstance(surface, (int, float, np.floating, np.integer)):
        return FlatSurface(float(surface))
    if callable(getattr(surface, "depth", None)) and hasattr(surface, "max_height"):
        return surface                       # a user's terrain (``depth(points, g_hat)``, ``max_height``): numpy backend
    raise ValueError(f"surface must be a height in m, a FlatSurface / HeightfieldSurface / SandRegion / "
                     f"DeformableSurface, or an object "
                     f"with depth(points, g_hat) and max_height, got {type(surface).__name__}")
