"""A free surface that bodies deform: footprints, berms and a loading memory (pure numpy, no MuJoCo).

3D-RFT (Agarwal, Goldman & Kamrin, PNAS 2023) gives the stress on an element from its depth below the
free surface and says nothing about what the intrusion does to that surface or to the sand under it. This
module adds that memory, in the terms of terramechanics, on a grid of nodes laid over the world xy-plane
(gravity along -z):

* **Footprint.** Where a body pierces the surface (its upward-facing surface over a node, if any, is above
  the node's surface) and its downward-facing surface is below the node's surface, the sand cannot stay
  there: the node is lowered to the body's surface (plus the elastic depth below); with several surfaces
  below a node (a lower leg over its foot), to the highest: the sand between them stays. A body entirely under
  the surface at a node (buried there) leaves the surface above it as it is: a heightfield cannot hold sand
  above a body, and removing it would take a buried body's depth away. Sand is measured at
  nodes: each node stands for one ``cell x cell`` patch, and volumes are ``sum(height change) * cell^2``.
* **Conservation.** The volume a body pushes out of the nodes it occupies is, less a compaction fraction
  (``compaction``, 0 by default: none compacted), deposited evenly on the ring of nodes within
  ``berm_width`` of the nodes it occupies that it does not occupy itself and that were never pressed
  (``preload == 0``; all the ring's nodes when none is virgin): a berm, kept out of earlier footprints (a
  wheel's rut is not refilled behind it). Volume leaves the grid only when that ring is empty (the body
  covers the whole grid); :func:`press` reports it. Then, around the body, slopes steeper than the angle
  of repose (``repose_angle``) flow downhill (:func:`relax`): the ring becomes a pile, trench walls slump;
  the nodes under the body take no part. Sand that a node receives (flowed or deposited) is loose: its
  thickness is taken off the node's preload (:func:`bury`), so a rut's slumped walls are pressed out again.
* **Loading memory.** Each node keeps ``preload`` q (m): the depth at which virgin sand carries the
  largest stress that node has carried (3D-RFT stress is proportional to depth for a given element
  orientation and motion, so a depth stands for a pressure: ``p = xi_n |alpha_gen| q``). An element at
  depth ``d`` below the *local deformed surface* (bilinear in the grid) is loaded as if at the
  effective depth (:func:`effective_depth`)

      d_eff = reload_ratio * d          while d <= q / reload_ratio   (reloading: stiff, elastic)
      d_eff = q + d - q / reload_ratio  beyond                         (the virgin line resumed)

  so sand reloads ``reload_ratio`` times stiffer than virgin sand up to the stress it has carried and
  follows the virgin behaviour beyond it. A node pressed past its elastic depth ``q / reload_ratio`` by
  ``delta`` (past the reload of the next bullet from the second loading cycle on) yields plastically:
  ``q += delta`` and the node is lowered so that the pressing point's effective depth is unchanged
  (:func:`press`). On virgin sand (q = 0 everywhere) ``d_eff = d``: the
  published law, depth from the undeformed surface, whatever the grid update's frequency.
* **Repeated loading.** Reloading to the stress already carried is not purely elastic: each node counts its
  loading cycles N (``cycles``; a cycle begins when a body presses a node that no body pressed at the
  previous update) and the fraction of its preload reached in the current cycle (``reach`` w, 0 to 1). In
  cycle N >= 2 the node settles plastically, at constant preload, by

      a_N q per unit of reach,   a_N = reload_sinkage * reload_decay ** (N - 2)

  so a full reload to the preload adds ``a_N q`` of sinkage at the same load: ``reload_sinkage * q`` in the
  second cycle, ``reload_decay`` times less in each later one (the sinkage grows with the number of cycles
  by diminishing increments and tends to ``reload_sinkage / (1 - reload_decay) * q`` more than the first
  cycle's). Reaching w takes ``w (q / reload_ratio + a_N q)`` of penetration into the rebounded surface;
  beyond w = 1 the virgin line resumes as above. The settled volume goes to the berm like any other.

What this is and is not. The loading/unloading/reloading behaviour is the repetitive-loading model of
terramechanics: Wong, *Theory of Ground Vehicles* (Wiley), and Bekker's pressure-sinkage work describe
plate tests in which soil unloaded from a sinkage rebounds little and, reloaded, follows a steep line back
to the largest pressure reached, then the virgin pressure-sinkage curve again. Chrono's Soil Contact Model
(SCM, Project Chrono ``SCMTerrain``) implements it on a height grid: per node a sinkage split into plastic
and elastic parts and a yield pressure, an elastic stiffness ``elastic_K`` (Pa/m, documented as larger
than the Bekker ``Kphi``), and optional bulldozing of displaced soil into berms. Here the virgin curve is
3D-RFT's (linear in depth, any element orientation) instead of Bekker's ``(k_c/b + k_phi) z^n``, and the
reload stiffness is a ratio to the virgin stiffness (``reload_ratio``, a modelling parameter, not measured
here: neither 3D-RFT nor this project has data for it). The plastic sinkage added by each reload, shrinking
with the number of cycles, is the trend that repeated plate loading and multi-pass wheel tests on sand report
(docs/deformable.md, "Repeated loading", with sources); its two numbers (``reload_sinkage`` 0.1,
``reload_decay`` 0.5) are this project's choice, not measured. 3D-RFT claims the virgin, quasi-static stress
on fresh, level-surfaced media; the footprint, berm, memory and repeated-loading rules are this module's
additions, not predictions of the paper.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rft_mujoco import tol
from rft_mujoco.physics import terrain_spec as ts

FACING_DOWN = 1e-6
"""An element presses the sand below it when its world normal has ``n_z < -FACING_DOWN``."""
YIELD_TOL = 1e-12
"""m: a node yields when pressed beyond its elastic depth by more than this, so that round-off (1e-18 m) never
starts the berm and the slope flow at a node that is only held."""
COVER_GROW = 0.5 - 1e-6
"""Cells by which an element's projected rectangle is grown to find the nodes it covers (:func:`covering`):
just under half a cell, so that a node half a cell beyond a body's outline is not covered."""


@dataclasses.dataclass(frozen=True, eq=False)
class DeformableSurface:
    """A sand surface that bodies deform, initially flat at ``height`` m (world z; gravity along -z).

    Attributes:
        height: initial surface height in m.
        size: (Lx, Ly) in m, the extent of the deformable grid; outside it the surface is the flat,
            undeformed one at ``height`` and keeps no memory.
        cell: node spacing in m (the grid has ``round(Lx / cell) + 1`` nodes along x; the spacing used is
            ``Lx / (nx - 1)``, and likewise along y).
        center: (x, y) in m, the centre of the grid.
        reload_ratio: stiffness of reloading over the virgin stiffness (dimensionless, > 1; default 20):
            a node that carried the stress of depth q reloads to it within ``q / reload_ratio`` of sinkage.
        reload_sinkage: plastic sinkage added by the first reload (second loading cycle) to the stress a node
            carried, as a fraction of its preload (dimensionless, >= 0; default 0.1; 0: reloading is elastic).
        reload_decay: each further loading cycle adds this fraction of the previous cycle's plastic sinkage
            (dimensionless, in [0, 1); default 0.5). Both are this project's choice, not measured.
        compaction: fraction of the displaced volume that compacts instead of going to the berm (0 to 1,
            default 0: volume conserved).
        berm_width: m, the displaced volume is spread evenly over the never-pressed nodes within this
            distance (at least one node) of the nodes the body occupies (default 0.05 m).
        repose_angle: degrees, around a pressing body slopes steeper than this flow until they are not
            (:func:`relax`: berms become piles, trench walls slump); None: no flow. Default 30 (dry sands and
            glass beads rest at roughly 20-35 degrees; a modelling parameter here, not measured).
        update_interval: s, the grid is updated (footprints, berms, memory, slope flow) at the first step at
            least this long after its last update (:func:`schedule`); 0: at every step. Between updates the
            sand's force is unchanged by the interval on virgin sand (an update keeps the pressing point's
            effective depth), the footprint lags the body by at most this long, and the slope flow runs its
            sweeps once per update. Default 0.03 (the cost and what it changes: docs/deformable.md, "The cost").
    """

    height: float = 0.0
    size: tuple[float, float] = (1.0, 1.0)
    cell: float = 0.005
    center: tuple[float, float] = (0.0, 0.0)
    reload_ratio: float = 20.0
    reload_sinkage: float = 0.1
    reload_decay: float = 0.5
    compaction: float = 0.0
    berm_width: float = 0.05
    repose_angle: float | None = 30.0
    update_interval: float = 0.03

    def __post_init__(self) -> None:
        if not math.isfinite(self.height):
            raise ValueError(f"height must be finite (m), got {self.height!r}")
        if not (math.isfinite(self.cell) and self.cell > 0.0):
            raise ValueError(f"cell must be a node spacing > 0 in m, e.g. 0.005, got {self.cell!r}")
        try:
            lx, ly = (float(v) for v in self.size)
            cx, cy = (float(v) for v in self.center)
        except (TypeError, ValueError):
            raise ValueError(f"size and center must be pairs of numbers in m, got size={self.size!r}, "
                             f"center={self.center!r}") from None
        if not (math.isfinite(lx) and math.isfinite(ly) and lx >= self.cell and ly >= self.cell):
            raise ValueError(f"size must be (Lx, Ly) in m, each at least one cell ({self.cell} m), got {self.size!r}")
        if not (math.isfinite(cx) and math.isfinite(cy)):
            raise ValueError(f"center must be a finite (x, y) in m, got {self.center!r}")
        nx, ny = int(round(lx / self.cell)) + 1, int(round(ly / self.cell)) + 1
        if nx * ny > 4_000_000:
            raise ValueError(f"the grid would have {nx} x {ny} nodes ({self.size!r} m at {self.cell} m); at most "
                             "4,000,000: use a coarser cell or a smaller size")
        if not (math.isfinite(self.reload_ratio) and self.reload_ratio > 1.0):
            raise ValueError(f"reload_ratio must be > 1 (reload stiffness over virgin stiffness), got "
                             f"{self.reload_ratio!r}")
        if not (math.isfinite(self.reload_sinkage) and self.reload_sinkage >= 0.0):
            raise ValueError(f"reload_sinkage must be a fraction of the preload >= 0 (0: elastic reloading), e.g. "
                             f"0.1, got {self.reload_sinkage!r}")
        if not (0.0 <= self.reload_decay < 1.0):
            raise ValueError(f"reload_decay must be in [0, 1) (each loading cycle's plastic sinkage over the "
                             f"previous one's), e.g. 0.5, got {self.reload_decay!r}")
        if not (0.0 <= self.compaction <= 1.0):
            raise ValueError(f"compaction must be a fraction in [0, 1], got {self.compaction!r}")
        if not (math.isfinite(self.berm_width) and self.berm_width >= 0.0):
            raise ValueError(f"berm_width must be >= 0 m, got {self.berm_width!r}")
        if not (math.isfinite(self.update_interval) and self.update_interval >= 0.0):
            raise ValueError(f"update_interval must be >= 0 s (0: update the grid at every step), e.g. 0.03, got "
                             f"{self.update_interval!r}")
        if self.repose_angle is not None and not (0.0 < self.repose_angle < 90.0):
            raise ValueError(f"repose_angle must be None or degrees in (0, 90), e.g. 30, got {self.repose_angle!r}")
        object.__setattr__(self, "size", (lx, ly))
        object.__setattr__(self, "center", (cx, cy))
        object.__setattr__(self, "shape", (ny, nx))
        object.__setattr__(self, "spacing", (lx / (nx - 1) if nx > 1 else lx, ly / (ny - 1) if ny > 1 else ly))
        object.__setattr__(self, "origin", (cx - lx / 2, cy - ly / 2))

    @property
    def x(self) -> np.ndarray:
        """(nx,) m, world x of the node columns."""
        return self.origin[0] + self.spacing[0] * np.arange(self.shape[1])

    @property
    def y(self) -> np.ndarray:
        """(ny,) m, world y of the node rows."""
        return self.origin[1] + self.spacing[1] * np.arange(self.shape[0])

    @property
    def max_height(self) -> float:
        """m, the initial surface height (the deformed surfaces of each MjData: :class:`DeformedSurface`)."""
        return float(self.height)

    def depth(self, points: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
        """(n,) m, depth of ``points`` (n, 3) below the *initial* surface (checks at attach use it)."""
        _check_gravity(g_hat)
        return self.height - np.asarray(points, float)[:, 2]

    def kernel_spec(self) -> ts.TerrainSpec:
        """Kind DEFORMABLE: the grid and its rules in ``tp`` (:data:`rft_mujoco.physics.terrain_spec.PARAMS`); the
        initial state (2 ny, nx): heights (m) over a zero preload (m), as each MjData's kernel array holds them."""
        berm, relax = max(1, int(math.floor(self.berm_width / min(self.spacing) + tol.ROUND_RTOL))), self.repose_angle
        tp = ts.new_params(height=self.height, max_height=self.height, grid_x0=self.origin[0],
                           grid_dx=self.spacing[0], grid_y0=self.origin[1], grid_dy=self.spacing[1],
                           reload_ratio=self.reload_ratio, reload_sinkage=self.reload_sinkage,
                           reload_decay=self.reload_decay, compaction=self.compaction, berm_cells=berm,
                           relax_cells=berm + 2, relax=relax is not None, cover_grow=COVER_GROW,
                           slope=0.0 if relax is None else math.tan(math.radians(relax)),
                           update_interval=self.update_interval)
        heights = np.zeros((2 * self.shape[0], self.shape[1]))
        heights[:self.shape[0]] = self.height
        return ts.TerrainSpec(ts.DEFORMABLE, tp, heights)

    def initial(self) -> "DeformedSurface":
        """A fresh, undeformed surface state of this grid."""
        return DeformedSurface(self, np.full(self.shape, float(self.height)), np.zeros(self.shape),
                               np.zeros(self.shape), np.zeros(self.shape))


def _check_gravity(g_hat: np.ndarray) -> None:
    if g_hat[2] > -1.0 + tol.VERTICAL_GRAVITY_TOL:
        raise ValueError(f"a deformable surface needs gravity along -z (heights are world z), got gravity "
                         f"direction {np.round(g_hat, 6).tolist()}")


SKIP, PRESS, RESTART = 0, 1, 2
"""What the grid update does at an evaluation (:func:`schedule`): nothing (not due), press (the loading goes
on), or unload every node and press (the time did not follow on from the last update)."""


def schedule(since_update: float, since_touch: float, interval: float, dt: float) -> int:
    """:data:`SKIP`, :data:`PRESS` or :data:`RESTART` for an evaluation with bodies touching ``since_update`` s after
    the grid's last update and ``since_touch`` s after the last evaluation with bodies touching (inf: none yet),
    with updates every ``interval`` s (``update_interval``) and steps of ``dt`` s. When the last step had nothing
    touching (or the time did not follow on: a reset, a jump, the first evaluation), every node is unloaded
    and the grid pressed now (:func:`unload`): a body that lifts off and lands again starts a new loading cycle
    however short the interval between; otherwise the grid is pressed when ``interval`` has passed since the
    last update. (A body that lifts and lands again while another one touches is seen only at the updates.)"""
    if not 0.0 <= since_touch <= dt * (1.0 + tol.TIME_RTOL):
        return RESTART
    return PRESS if since_update >= interval * (1.0 - tol.TIME_RTOL) else SKIP


def effective_depth(d: np.ndarray, q: np.ndarray, reload_ratio: float) -> np.ndarray:
    """(n,) m, the depth at which virgin sand carries the stress of an element ``d`` (n,) m below the local
    deformed surface where the sand has carried the stress of depth ``q`` (n,) m (module docstring).
    ``d <= 0`` (above the surface) is returned unchanged."""
    e = q / reload_ratio
    return np.where(d <= 0.0, d, np.where(d <= e, reload_ratio * d, q + d - e))


def cycle_sinkage(grid: DeformableSurface, cycles: np.ndarray) -> np.ndarray:
    """(n,) dimensionless, ``a_N``: the plastic sinkage per unit of reach, over the preload, of nodes in their
    ``cycles`` (n,)-th loading cycle (module docstring): 0 in the first, ``reload_sinkage *
    reload_decay ** (N - 2)`` from the second on."""
    n = np.asarray(cycles, float)
    return np.where(n >= 2.0, grid.reload_sinkage * grid.reload_decay ** np.maximum(n - 2.0, 0.0), 0.0)


def bilinear(grid: DeformableSurface, values: np.ndarray, x: np.ndarray, y: np.ndarray):
    """``(v (n,), inside (n,) bool)``: ``values`` (ny, nx) bilinearly interpolated at world (x, y) (n,) m;
    ``inside`` marks points over the grid (``v`` there; clamped to the border elsewhere)."""
    ny, nx = grid.shape
    u = (np.asarray(x, float) - grid.origin[0]) / grid.spacing[0]
    w = (np.asarray(y, float) - grid.origin[1]) / grid.spacing[1]
    inside = (u >= 0) & (u <= nx - 1) & (w >= 0) & (w <= ny - 1)
    u = np.clip(np.nan_to_num(u), 0, nx - 1)
    w = np.clip(np.nan_to_num(w), 0, ny - 1)
    i0 = np.minimum(np.floor(w).astype(np.int64), max(ny - 2, 0))
    j0 = np.minimum(np.floor(u).astype(np.int64), max(nx - 2, 0))
    i1, j1 = np.minimum(i0 + 1, ny - 1), np.minimum(j0 + 1, nx - 1)
    fu, fw = u - j0, w - i0
    v = ((1 - fw) * ((1 - fu) * values[i0, j0] + fu * values[i0, j1])
         + fw * ((1 - fu) * values[i1, j0] + fu * values[i1, j1]))
    return v, inside


class DeformedSurface:
    """The state of a :class:`DeformableSurface` in one simulation: a terrain (``depth``, ``max_height``).

    Attributes:
        grid: the :class:`DeformableSurface` it belongs to.
        heights: (ny, nx) m, surface height at the nodes (row i at ``y[i]``, column j at ``x[j]``).
        preload: (ny, nx) m, the depth-equivalent of the largest stress each node has carried (module
            docstring); 0 on virgin sand.
        cycles: (ny, nx), the loading cycles each node has begun (0 on virgin sand; module docstring).
        reach: (ny, nx), the fraction of its preload each node has been reloaded to in its current cycle (0 to 1;
            0 when no body presses it).
    The arrays may be views of a caller's memory (the coupling keeps them in a handle's workspace).
    """

    __slots__ = ("grid", "heights", "preload", "cycles", "reach")

    def __init__(self, grid: DeformableSurface, heights: np.ndarray, preload: np.ndarray, cycles: np.ndarray,
                 reach: np.ndarray) -> None:
        shapes = [a.shape for a in (heights, preload, cycles, reach)]
        if any(sh != grid.shape for sh in shapes):
            raise ValueError(f"heights, preload, cycles and reach must have the grid's shape {grid.shape}, got "
                             f"{shapes}")
        self.grid, self.heights, self.preload, self.cycles, self.reach = grid, heights, preload, cycles, reach

    @property
    def x(self) -> np.ndarray:
        return self.grid.x

    @property
    def y(self) -> np.ndarray:
        return self.grid.y

    @property
    def max_height(self) -> float:
        """m, the highest point of the surface (a berm may be above the initial height)."""
        return max(float(self.heights.max()), float(self.grid.height))

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(n,) m, the surface height at world (x, y) (n,): bilinear over the grid, ``height`` outside."""
        h, inside = bilinear(self.grid, self.heights, x, y)
        return np.where(inside, h, self.grid.height)

    def depth(self, points: np.ndarray, g_hat: np.ndarray) -> np.ndarray:
        """(n,) m, the effective depth (:func:`effective_depth`) of ``points`` (n, 3), measured from the local
        deformed surface with the local preload; > 0 below the surface."""
        _check_gravity(g_hat)
        points = np.asarray(points, float)
        h, inside = bilinear(self.grid, self.heights, points[:, 0], points[:, 1])
        q, _ = bilinear(self.grid, self.preload, points[:, 0], points[:, 1])
        h = np.where(inside, h, self.grid.height)
        q = np.where(inside, q, 0.0)
        return effective_depth(h - points[:, 2], q, self.grid.reload_ratio)

    def copy(self) -> "DeformedSurface":
        return DeformedSurface(self.grid, self.heights.copy(), self.preload.copy(), self.cycles.copy(),
                               self.reach.copy())


@dataclasses.dataclass(frozen=True)
class PressResult:
    """What one :func:`press` did (volumes in m^3, measured as ``sum(height change) * cell area``).

    Attributes:
        covered: nodes under a downward-facing element.
        yielded: nodes pressed past their preload (the virgin line: preload grown, node lowered).
        settled: nodes lowered by the plastic sinkage of a reload (loading cycle 2 or later, below the preload).
        displaced: volume pushed out of the yielded nodes.
        deposited: volume added to the berm (``(1 - compaction) * displaced`` unless ``lost``).
        lost: volume that found no berm node (the footprint covers the whole grid).
    """

    covered: int
    yielded: int
    displaced: float
    deposited: float
    lost: float
    settled: int = 0


_NOTHING = PressResult(0, 0, 0.0, 0.0, 0.0)


def covering(grid: DeformableSurface, points: np.ndarray, normals: np.ndarray, areas: np.ndarray,
             facing: int = -1, below: np.ndarray | None = None):
    """The nodes under the downward-facing elements and the lowest body surface over each (``facing=+1``: the
    nodes under the upward-facing elements and the highest body surface over each; ``below`` (ny * nx,) m:
    downward-facing surfaces only where they are below it, and the *highest* of them over each node: the first
    body surface that sand coming down the node's column meets).

    Each element with ``n_z < -FACING_DOWN`` stands for a square of side ``L = sqrt(area)`` in its own plane,
    with one side along the plane's horizontal direction; its projection on the xy-plane is the rectangle
    centred on the centroid with half-sides ``L / 2`` across the tilt direction ``t`` (the horizontal part of
    the normal) and ``|n_z| L / 2`` along it (``t = x`` for a level element). The nodes in that rectangle
    grown by :data:`COVER_GROW` of a cell on each side (elements are not all square: without it, nodes
    between the elements of a body's bottom could stay uncovered) are covered, at the height of the
    element's plane over the node, the node's offset along the tilt clamped to the element (no plane is
    extrapolated beyond its element). Returns ``(flat node indices (m,), lowest body height over each (m,) m)``.

    Args:
        points: (n, 3) m, element centroids (world).
        normals: (n, 3) outward unit normals (world).
        areas: (n,) m^2.
    """
    nz = normals[:, 2] * -facing
    down = np.flatnonzero(nz < -FACING_DOWN)
    if down.size == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    p, n = points[down], normals[down]
    half = 0.5 * np.sqrt(areas[down])                                                 # (k,) m
    flat_h = np.sqrt(n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1])
    level = flat_h <= FACING_DOWN
    tx = np.where(level, 1.0, n[:, 0] / np.where(level, 1.0, flat_h))                 # tilt direction (k,)
    ty = np.where(level, 0.0, n[:, 1] / np.where(level, 1.0, flat_h))
    along = half * np.abs(n[:, 2])
    sx, sy = grid.spacing
    ny, nx = grid.shape
    k = int(math.ceil(float(half.max()) / min(sx, sy))) + 2
    off = np.arange(-k, k + 1)
    jc = np.rint((p[:, 0] - grid.origin[0]) / sx).astype(np.int64)
    ic = np.rint((p[:, 1] - grid.origin[1]) / sy).astype(np.int64)
    jj = jc[:, None, None] + off[None, None, :]                                       # (k, 1, o)
    ii = ic[:, None, None] + off[None, :, None]                                       # (k, o, 1)
    dx = grid.origin[0] + sx * jj - p[:, 0, None, None]
    dy = grid.origin[1] + sy * ii - p[:, 1, None, None]
    u = dx * tx[:, None, None] + dy * ty[:, None, None]                               # along the tilt
    w = dy * tx[:, None, None] - dx * ty[:, None, None]                               # across it
    grow = COVER_GROW * min(sx, sy)
    hit = ((np.abs(u) <= along[:, None, None] + grow) & (np.abs(w) <= half[:, None, None] + grow)
           & (jj >= 0) & (jj < nx) & (ii >= 0) & (ii < ny))
    # the element's plane over the node, at the node's offset along the tilt clamped to the element (grown
    # nodes and nearly vertical elements do not extrapolate the plane beyond the element)
    u = np.clip(u, -along[:, None, None], along[:, None, None])
    z = p[:, 2, None, None] - (flat_h / n[:, 2])[:, None, None] * u
    e, a, b = np.nonzero(hit)
    flat = ii[e, a, 0] * nx + jj[e, 0, b]
    zb = z[e, a, b]
    if below is not None:
        under = zb < below[flat]
        flat, zb = flat[under], zb[under]
    nodes, inv = np.unique(flat, return_inverse=True)
    if facing > 0 or below is not None:
        high = np.full(nodes.size, -np.inf)
        np.maximum.at(high, inv, zb)
        return nodes, high
    low = np.full(nodes.size, np.inf)
    np.minimum.at(low, inv, zb)
    return nodes, low


def press(surface: DeformedSurface, points: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> PressResult:
    """Deform ``surface`` in place under a body's exposed surface elements (module docstring).

    Args:
        surface: the state to update.
        points: (n, 3) m, element centroids (world), e.g. the submerged elements of one evaluation.
        normals: (n, 3) their outward unit normals (world).
        areas: (n,) m^2.
    Returns:
        a :class:`PressResult`.
    """
    grid = surface.grid
    points = np.asarray(points, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    areas = np.asarray(areas, float).reshape(-1)
    if not (normals.shape[0] == points.shape[0] == areas.shape[0]):
        raise ValueError(f"points (n, 3), normals (n, 3) and areas (n,) must have one row per element, got "
                         f"{points.shape}, {normals.shape}, {areas.shape}")
    h = surface.heights.reshape(-1)
    q = surface.preload.reshape(-1)
    reach = surface.reach.reshape(-1)
    nodes, low = covering(grid, points, normals, areas, below=h)
    if nodes.size:
        # only where the body pierces the surface (no upward-facing surface of it below the sand there): a buried
        # body leaves the sand above it in place
        up, high = covering(grid, points, normals, areas, facing=+1)
        top = np.full(nodes.size, np.inf)
        at = np.searchsorted(up, nodes)
        found = at < up.size
        found[found] = up[at[found]] == nodes[found]
        top[found] = high[at[found]]
        keep = top >= h[nodes]
        nodes, low = nodes[keep], low[keep]
    w0 = reach[nodes]                                # (m,) reach so far in this cycle (0: a new cycle)
    reach.fill(0.0)                                  # the nodes no body presses now are unloaded
    if nodes.size == 0:
        return _NOTHING
    cycles = surface.cycles.reshape(-1)
    cycles[nodes[w0 == 0.0]] += 1.0
    ratio = grid.reload_ratio
    qn = q[nodes]
    elastic = qn / ratio                             # m of penetration per unit of reach: elastic ...
    settle_rate = cycle_sinkage(grid, cycles[nodes]) * qn     # ... and plastic at constant preload
    rate = elastic + settle_rate
    push = h[nodes] - low - w0 * elastic             # m beyond the reach already taken (> 0 presses further)
    along = np.clip(np.minimum(push, (1.0 - w0) * rate), 0.0, None)       # reloading, up to the preload
    w1 = np.where(rate > 0.0, w0 + along / np.where(rate > 0.0, rate, 1.0), 1.0)   # virgin node: reach 1
    beyond = push - along                            # > 0 past the preload: the virgin line
    yielded = beyond > YIELD_TOL
    settle = settle_rate * (w1 - w0)
    reach[nodes] = np.where(yielded, 1.0, w1)
    q_new = np.where(yielded, qn + beyond, qn)
    new_h = np.where(yielded, low + q_new / ratio, h[nodes] - settle)
    lowered = yielded | (settle > 0.0)
    n_yield, n_settle = int(np.count_nonzero(yielded)), int(np.count_nonzero(lowered & ~yielded))
    if not lowered.any():
        return PressResult(int(nodes.size), 0, 0.0, 0.0, 0.0)
    q[nodes] = q_new
    ln = nodes[lowered]
    cell_area = grid.spacing[0] * grid.spacing[1]
    displaced = float(np.sum(h[ln] - new_h[lowered])) * cell_area
    h[ln] = new_h[lowered]
    volume = (1.0 - grid.compaction) * displaced
    rim = berm_nodes(grid, nodes)
    virgin = rim[q[rim] == 0.0]
    rim = virgin if virgin.size else rim
    if rim.size == 0:
        return PressResult(int(nodes.size), n_yield, displaced, 0.0, volume, n_settle)
    h[rim] += volume / (rim.size * cell_area)
    q[rim] = np.maximum(q[rim] - volume / (rim.size * cell_area), 0.0)     # :func:`bury` (rim nodes are unique)
    if grid.repose_angle is not None:
        relax(surface, nodes)
    return PressResult(int(nodes.size), n_yield, displaced, volume, 0.0, n_settle)


def unload(surface: DeformedSurface) -> None:
    """Every node of ``surface`` unloaded (in place): no body pressed it since the last :func:`press`, so the next
    press of a node begins a new loading cycle (the coupling calls this when a step went by without a press)."""
    surface.reach.fill(0.0)


RELAX_ITERATIONS = 10
"""Sweeps of :func:`relax` per :func:`press`."""
RELAX_SHARE = 0.125
"""Fraction of a pair's excess height difference moved per sweep (1/8: a node can give to its four neighbours in
one sweep without overshooting)."""


def relax(surface: DeformedSurface, covered: np.ndarray) -> None:
    """Let slopes steeper than the angle of repose flow (in place, volume conserved): around the ``covered``
    nodes (flat indices; they exchange nothing: the body holds them), at the nodes within the berm width and
    two cells more of them (Chebyshev distance, in nodes: around each body, not over the box that holds them
    all), :data:`RELAX_ITERATIONS` sweeps move :data:`RELAX_SHARE` of each neighbouring pair's height difference
    beyond ``tan(repose_angle) * spacing`` from the higher node to the lower one (along x and along y). The
    nodes that gained sand are buried under it (:func:`bury`: the sand that flowed is loose); those that lost
    some keep their preload."""
    grid = surface.grid
    ny, nx = grid.shape
    sx, sy = grid.spacing
    r = max(1, int(math.floor(grid.berm_width / min(sx, sy) + tol.ROUND_RTOL))) + 2
    ci, cj = np.divmod(covered, nx)
    i0, i1 = max(int(ci.min()) - r, 0), min(int(ci.max()) + r, ny - 1) + 1
    j0, j1 = max(int(cj.min()) - r, 0), min(int(cj.max()) + r, nx - 1) + 1
    h = surface.heights[i0:i1, j0:j1]                 # a view: updated in place
    free = _dilated(ci - i0, cj - j0, h.shape, r)   # within r nodes (Chebyshev) of a covered node ...
    free[ci - i0, cj - j0] = False                  # ... and not covered
    slope = math.tan(math.radians(grid.repose_angle))
    pair_x = free[:, 1:] & free[:, :-1]
    pair_y = free[1:, :] & free[:-1, :]
    before = h.copy()
    for _ in range(RELAX_ITERATIONS):
        d = h[:, 1:] - h[:, :-1]
        f = np.where(pair_x, RELAX_SHARE * np.sign(d) * np.maximum(np.abs(d) - slope * sx, 0.0), 0.0)
        h[:, 1:] -= f
        h[:, :-1] += f
        d = h[1:, :] - h[:-1, :]
        f = np.where(pair_y, RELAX_SHARE * np.sign(d) * np.maximum(np.abs(d) - slope * sy, 0.0), 0.0)
        h[1:, :] -= f
        h[:-1, :] += f
    bury(surface.preload[i0:i1, j0:j1], h - before)


def _dilated(ci: np.ndarray, cj: np.ndarray, shape: tuple[int, int], r: int) -> np.ndarray:
    """(shape) bool: the nodes within ``r`` nodes (Chebyshev distance) of the nodes (``ci``, ``cj``) of a window of
    ``shape`` (themselves included)."""
    rows, cols = shape
    win = np.zeros(shape, dtype=bool)
    win[ci, cj] = True
    wide = win.copy()                                # along x, then along y
    for b in range(1, r + 1):
        wide[:, b:] |= win[:, :cols - b]
        wide[:, :cols - b] |= win[:, b:]
    grown = wide.copy()
    for a in range(1, r + 1):
        grown[a:, :] |= wide[:rows - a, :]
        grown[:rows - a, :] |= wide[a:, :]
    return grown


def bury(preload: np.ndarray, added: np.ndarray) -> None:
    """Loose sand of thickness ``added`` (m; where > 0) laid on nodes of preload ``preload`` (m, in place; the
    arrays of the same shape): ``preload = max(preload - added, 0)``. The loose layer carries no memory and loads
    the column under it by its own depth, so a body reaching the node's remembered stress again does so at the
    same place as over a virgin layer on the remembered column, and follows the same virgin line beyond it
    (docs/deformable.md, "Loose sand on a pressed node")."""
    np.maximum(preload - np.maximum(added, 0.0), 0.0, out=preload)


def berm_nodes(grid: DeformableSurface, covered: np.ndarray) -> np.ndarray:
    """(r,) flat indices of the nodes within ``berm_width`` (Chebyshev distance, at least one node) of the
    ``covered`` nodes (flat indices) and not covered themselves."""
    ny, nx = grid.shape
    r = max(1, int(math.floor(grid.berm_width / min(grid.spacing) + tol.ROUND_RTOL)))
    ci, cj = np.divmod(covered, nx)
    i0, i1 = max(int(ci.min()) - r, 0), min(int(ci.max()) + r, ny - 1)
    j0, j1 = max(int(cj.min()) - r, 0), min(int(cj.max()) + r, nx - 1)
    shape = (i1 - i0 + 1 + 2 * r, j1 - j0 + 1 + 2 * r)
    rows, cols = shape
    win = np.zeros(shape, dtype=bool)
    win[ci - i0 + r, cj - j0 + r] = True
    ring = _dilated(ci - i0 + r, cj - j0 + r, shape, r) & ~win
    wi, wj = np.nonzero(ring[r:rows - r, r:cols - r])
    return (wi + i0) * nx + (wj + j0)


def volume_change(surface: DeformedSurface) -> float:
    """m^3, the net change of sand volume over the grid since the surface was flat at its initial height
    (``sum(heights - height) * cell area``; 0 when volume was conserved)."""
    g = surface.grid
    return float(np.sum(surface.heights - g.height)) * g.spacing[0] * g.spacing[1]


def footprint_volume(surface: DeformedSurface) -> float:
    """m^3, the volume of the depressions below the initial height (``sum(max(height - h, 0)) * cell
    area``)."""
    g = surface.grid
    return float(np.sum(np.maximum(g.height - surface.heights, 0.0))) * g.spacing[0] * g.spacing[1]
