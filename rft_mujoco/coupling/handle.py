"""MuJoCo coupling: attach 3D-RFT sand to bodies of a model; plain ``mujoco.mj_step`` then includes it.

Each physics evaluation (every integrator stage: once per step for Euler/implicit/implicitfast, four
times for RK4) the dispatcher (:mod:`rft_mujoco.coupling.dispatch`) calls :meth:`SandHandle._evaluate`, which

1. skips bodies whose bounding sphere is above the highest point of the sand (broadphase), and finds
   the bodies that touch the sand (an element with depth > 0); nothing else runs when none does;
2. takes element positions and normals from ``xpos``/``xmat`` and body velocities from ``cvel`` (whose
   linear part refers to ``subtree_com`` of the root, converted to each body's COM);
3. with ``stabilize=True`` (default), the rest treatment of :mod:`rft_mujoco.physics.rest`: per touching
   *group* (the attached bodies of one MuJoCo weld group, i.e. one rigid body) the free twist at the end
   of the step without sand, from the smooth forces of this evaluation and the constraint forces of
   MuJoCo's previous solve (``qfrc_constraint``: contacts, equalities, joint/tendon limits,
   frictionloss); the RFT wrench at the blended motion direction; the rest wrenches that hold every
   group the sand can hold, solved together through ``J M^-1 J^T``, and the published force for the
   others. With ``stabilize=False``, the published force at each element's velocity (the naive
   coupling);
4. adds the wrenches to ``data.xfrc_applied`` on top of the user's own wrench (the dispatcher's book);
5. every ``monitor.every`` evaluations, checks the loaded bodies against the validity range of 3D-RFT
   (:mod:`rft_mujoco.coupling.monitor`; ``attach(monitor=False)`` switches it off).

Steps 1-3 run compiled (:mod:`rft_mujoco.compiled.elements`, :mod:`rft_mujoco.compiled.rest`; ``backend="numba"``,
the default where numba imports) or in the numpy reference below (``backend="numpy"``); the tests compare
the two. Costs are measured by ``python -m rft_mujoco bench``.

Why the constraint forces of the previous solve: MuJoCo calls ``mjcb_control`` before its constraint
solve, so no force computed there can know this step's contact, weld or limit forces; the previous
solve's are the best estimate, exact once the scene rests (``../shared/reference/mujoco-notes.md``;
the design and its alternatives are measured in docs/rest.md).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
import weakref
from collections.abc import Sequence

import mujoco
import numpy as np

from rft_mujoco.compiled import elements as fastkernel
from rft_mujoco.compiled import rest as fastrest
from rft_mujoco.physics import elements as kernel
from rft_mujoco.physics import law
from rft_mujoco.physics import rest
from rft_mujoco.geometry import surface
from rft_mujoco import tol
from rft_mujoco.coupling.dispatch import DISPATCHER
from rft_mujoco.physics.law import PUBLISHED, Guards, gravity_direction
from rft_mujoco.physics.media import Media, get_media
from rft_mujoco.coupling.monitor import ValidityMonitor
from rft_mujoco.physics.terrain import Terrain, as_terrain


@dataclasses.dataclass
class Diagnostics:
    """Per-body sand state of one evaluation of one MjData (arrays over ``SandHandle.body_ids``).

    Attributes:
        force: (B, 3) N, world frame, applied at each body's COM.
        torque: (B, 3) N m, world frame, about each body's COM.
        submerged: (B,) int, number of submerged leading elements that carried stress.
        max_depth: (B,) m, deepest loaded element (0 when none).
        scale: (B,) ``|applied wrench| / |RFT wrench|`` (torques over the body's radius): 1 in flow,
            the fraction of its capacity the sand uses to hold a resting body.
        rft_force: (B, 3) N, the RFT force at the body's motion direction (its capacity at rest).
        resting: (B,) bool, the body is held at rest by the sand (False: in flow, or not loaded).
    """

    force: np.ndarray
    torque: np.ndarray
    submerged: np.ndarray
    max_depth: np.ndarray
    scale: np.ndarray
    rft_force: np.ndarray
    resting: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> "Diagnostics":
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, dtype=np.int64), np.zeros(n),
                   np.ones(n), np.zeros((n, 3)), np.zeros(n, dtype=bool))

    def copy(self) -> "Diagnostics":
        """A snapshot that later evaluations do not change."""
        return Diagnostics(*(np.array(getattr(self, f.name)) for f in dataclasses.fields(self)))

    def clear(self) -> None:
        """Zero wrenches, counts and depths; scale 1; nothing resting (an evaluation without sand)."""
        self.force[:] = 0.0
        self.torque[:] = 0.0
        self.submerged[:] = 0
        self.max_depth[:] = 0.0
        self.scale[:] = 1.0
        self.rft_force[:] = 0.0
        self.resting[:] = False


BACKENDS = ("auto", "numba", "numpy")
"""Kernel backends of :func:`attach`: numba-compiled (:mod:`rft_mujoco.compiled.elements`,
:mod:`rft_mujoco.compiled.rest`) or numpy (:mod:`rft_mujoco.physics.elements`, :mod:`rft_mujoco.physics.rest`, the readable
reference); "auto" is numba when it imports and supports the terrain, numpy otherwise."""
RK4_STAGES = ("all", "first")
"""Values of ``attach(rk4_stages=...)``: evaluate the sand at every RK4 stage, or at the first and hold it."""


class _Workspace:
    """Per-MjData state of one handle (datas may be stepped in different threads): the diagnostics, the
    time of the last evaluation, and rows 0..k-1 of the touching bodies' poses and velocities."""

    __slots__ = ("diag", "touch", "body_pos", "body_mat", "body_com", "v_com", "omega", "groups", "count",
                 "max_depth", "scratch", "last_time", "clean", "fast")

    def __init__(self, n_bodies: int, compiled: bool) -> None:
        b = n_bodies
        self.diag = Diagnostics.zeros(b)
        self.touch = np.zeros(b, dtype=np.int64)
        self.body_pos, self.body_com, self.v_com, self.omega = (np.zeros((b, 3)) for _ in range(4))
        self.body_mat = np.zeros((b, 9))
        self.groups = np.zeros((b, kernel.GROUPS_PER_BODY, 6))
        self.count = np.zeros(b, dtype=np.int64)
        self.max_depth = np.zeros(b)
        self.scratch = np.zeros((fastkernel.SCRATCH_ROWS, fastkernel.CLUSTER_SIZE)) if compiled else None
        self.last_time = -math.inf
        self.clean = True
        self.fast = None            # the compiled rest evaluation's buffers (rft_mujoco.compiled.rest.Buffers)

    def follow_time(self, t: float, dt: float) -> bool:
        """Record an evaluation at time ``t``; True when time advanced by at most one step since the last
        one (RK4 stages included): only then is MuJoCo's previous constraint solve this motion's."""
        continuous = 0.0 <= t - self.last_time <= dt * (1.0 + tol.TIME_RTOL)
        self.last_time = t
        return continuous


def _body_id(model, name) -> int:
    if isinstance(name, (int, np.integer)):
        if not 0 < int(name) < model.nbody:
            raise ValueError(f"body id {name} out of range 1..{model.nbody - 1} (0 is the world)")
        return int(name)
    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    if bid < 0:
        names = [model.body(i).name for i in range(1, model.nbody)]
        raise ValueError(f"no body named {name!r} in the model; bodies are {names}")
    if bid == 0:
        raise ValueError("the world body cannot be a sand intruder")
    return bid


MAX_ELEMENTS_PER_BODY = 1_000_000
"""Most surface elements one body may be cut into (memory and time guard against absurd resolutions)."""


def _check_element_count(model, body_id: int, name: str, size: float) -> None:
    """Raise before tessellating if ``size`` would cut the body into more than MAX_ELEMENTS_PER_BODY."""
    geoms = np.flatnonzero(model.geom_bodyid == body_id)
    area = sum(4.0 * np.pi * float(model.geom_rbound[g]) ** 2 for g in geoms
               if model.geom_type[g] not in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD))
    estimate = area / size**2
    if estimate > MAX_ELEMENTS_PER_BODY:
        coarsest = math.sqrt(area / MAX_ELEMENTS_PER_BODY)
        raise ValueError(f"resolution {size:g} m would cut body {name!r} (surface ~{area:.3g} m^2) into about "
                         f"{estimate:.3g} surface elements (limit {MAX_ELEMENTS_PER_BODY}); use an element "
                         f"size of at least {coarsest:.3g} m, or a preset name "
                         f"{dict(surface.RESOLUTIONS)}")


@dataclasses.dataclass(frozen=True, eq=False)
class Groups:
    """The attached bodies of one handle grouped by MuJoCo weld group (bodies welded together move as one).

    Attributes:
        of_body: (B,) int, the group of each attached body.
        ref: (G,) int, the attached body (index into ``body_ids``) whose COM is the group's reference point.
        radius: (G,) m, radius about the reference point of a sphere holding the group's elements.
    """

    of_body: np.ndarray
    ref: np.ndarray
    radius: np.ndarray


def _groups(model, body_ids: np.ndarray, centroids: np.ndarray, elem_body: np.ndarray, size: float) -> Groups:
    weld = model.body_weldid[body_ids]
    keys, of_body = np.unique(weld, return_inverse=True)
    ref = np.array([int(np.flatnonzero(of_body == g)[0]) for g in range(keys.size)], dtype=np.int64)
    data = mujoco.MjData(model)                 # the relative poses inside a weld group never change
    mujoco.mj_kinematics(model, data)
    radius = np.full(keys.size, size)
    for i, b in enumerate(body_ids):
        pts = centroids[elem_body == i]
        if not pts.size:
            continue
        world = data.xpos[b] + pts @ data.xmat[b].reshape(3, 3).T
        g = of_body[i]
        far = float(np.linalg.norm(world - data.xipos[body_ids[ref[g]]], axis=1).max())
        radius[g] = max(radius[g], far + size)
    return Groups(of_body.astype(np.int64), ref, radius)


class SandHandle:
    """Sand attached to some bodies of one MjModel. Create with :func:`attach`; remove with :meth:`detach`.

    Attributes:
        model: the MjModel.
        media: the granular medium.
        terrain: the free surface.
        body_ids: (B,) int, bodies that feel the sand.
        body_names: their names.
        n_elements: total surface elements (candidates) over those bodies.
        evaluations: sand evaluations so far (all MjData together).
        stabilize: the rest treatment is on (see :func:`attach`).
        rk4_stages: with integrator="RK4", "all" or "first" (see :func:`attach`).
    """

    def __init__(self, model, media: Media, body_ids: Sequence[int], terrain: Terrain, size: float,
                 guards: Guards, stabilize: bool, passive: bool, monitor: bool | ValidityMonitor = True,
                 backend: str = "auto"):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self._backend_request = None
        self.model = model
        self.media = media
        self.terrain = terrain
        self.guards = guards
        self.stabilize = bool(stabilize)
        self.passive = bool(passive)
        self.element_size = size
        self.body_ids = np.asarray(body_ids, dtype=np.int64)
        self.body_names = [model.body(int(b)).name for b in self.body_ids]
        parts, counts = [], []
        for b, name in zip(self.body_ids, self.body_names):
            _check_element_count(model, int(b), name, size)
            try:
                el = surface.body_elements(model, int(b), size)
            except ValueError as exc:
                raise ValueError(f"cannot cut body {name!r} into surface elements: {exc}. Check the sizes of "
                                 "its geoms (each needs a surface with a non-zero area) or leave the body "
                                 "out of bodies=") from None
            # The sand wrench acts on the body's weld group (the body and everything welded to it).
            mass = model.body_subtreemass[model.body_weldid[b]]
            if len(el) and mass <= 0:
                raise ValueError(f"body {name!r} has zero mass (mass of its weld group {mass}); "
                                 "sand forces on a massless body have nothing to act on: give it a mass "
                                 "or leave it out of bodies=")
            parts.append(el)
            counts.append(len(el))
        if sum(counts) == 0:
            raise ValueError(f"bodies {self.body_names} have no surface geoms (planes and heightfields are "
                             "terrain, not intruders); choose bodies with sphere/capsule/box/... geoms")
        el = surface.Elements.concatenate(parts)
        self.local_centroids = np.ascontiguousarray(el.centroids)
        self.local_normals = np.ascontiguousarray(el.normals)
        self.areas = np.ascontiguousarray(el.areas)
        self.elem_body = np.repeat(np.arange(len(self.body_ids)), counts)
        self.n_elements = int(self.areas.size)
        # Bounding spheres in the body frame (centre, radius) for the broadphase.
        self._bound_center = np.zeros((len(self.body_ids), 3))
        self._bound_radius = np.full(len(self.body_ids), -np.inf)
        for i, c in enumerate(counts):
            if c:
                pts = self.local_centroids[self.elem_body == i]
                lo, hi = pts.min(0), pts.max(0)
                center = 0.5 * (lo + hi)
                self._bound_center[i] = center
                self._bound_radius[i] = np.linalg.norm(pts - center, axis=1).max() + size
        self._elem_slices = np.ascontiguousarray(np.concatenate([[0], np.cumsum(counts)]), dtype=np.int64)
        self.elem_octant = kernel.octants(self.local_centroids, self._bound_center[self.elem_body])
        self.groups = _groups(model, self.body_ids, self.local_centroids, self.elem_body, size)
        self._work: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
        self._root = np.ascontiguousarray(model.body_rootid[self.body_ids], dtype=np.int64)
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self.attached = False
        self._evaluations = np.zeros(1, dtype=np.int64)
        self.monitor = (monitor if isinstance(monitor, ValidityMonitor) else
                        ValidityMonitor() if monitor else None)
        self._replaced: list[tuple[int, int, int]] = []
        self._opt = model.opt
        self._opt_gravity = model.opt.gravity            # a live view: gravity changes are seen
        self._gravity_seen = None
        self._tol = fastkernel.tolerances()
        self._settings = np.array([rest.DEPENDENT_TOL, rest.WEIGHT_FLOOR, rest.CAPACITY_TOL, tol.TINY])
        self._tree = tuple(np.ascontiguousarray(a, dtype=np.int64) for a in (
            model.body_rootid, model.body_dofnum, model.body_dofadr, model.body_parentid, model.dof_parentid,
            model.M_rownnz, model.M_rowadr, model.M_colind))
        self._layout_ok = None                          # fastrest.check_layout, once
        self.rk4_stages = "all"
        self._backend_request = backend
        self._select_backend()

    # --- public -------------------------------------------------------------------------------------
    @property
    def evaluations(self) -> int:
        """Sand evaluations so far (all MjData together)."""
        return int(self._evaluations[0])

    @property
    def media(self) -> Media:
        """The granular medium; may be replaced between steps (e.g. per-episode randomization)."""
        return self._media

    @media.setter
    def media(self, value: Media) -> None:
        if not isinstance(value, Media):
            raise TypeError(f"media must be a rft_mujoco.Media, got {type(value).__name__}; "
                            "use rft_mujoco.get_media(name) for a preset")
        self._media = value

    def detach(self) -> None:
        """Remove the sand: later steps are the plain model; sand wrenches are taken out of xfrc_applied."""
        if not self.attached:
            return
        DISPATCHER.unregister(self)
        for gid, contype, conaffinity in self._replaced:
            self.model.geom_contype[gid] = contype
            self.model.geom_conaffinity[gid] = conaffinity
        self._replaced.clear()
        for data in DISPATCHER.datas_of(self.model):
            DISPATCHER.remove_sand(self.model, data, self.body_ids)
        self.attached = False

    def replace_rigid(self, geoms: Sequence[str | int]) -> None:
        """Switch off collisions of rigid geoms the sand replaces (e.g. the floor plane) until detach."""
        for g in geoms:
            gid = g if isinstance(g, (int, np.integer)) else mujoco.mj_name2id(
                self.model, mujoco.mjtObj.mjOBJ_GEOM, g)
            if gid < 0 or gid >= self.model.ngeom:
                raise ValueError(f"no geom named {g!r} to replace by sand")
            self._replaced.append((int(gid), int(self.model.geom_contype[gid]),
                                   int(self.model.geom_conaffinity[gid])))
            self.model.geom_contype[gid] = 0
            self.model.geom_conaffinity[gid] = 0

    def diagnostics(self, data) -> Diagnostics:
        """Per-body force, torque, submerged element count, max depth and rest state of the latest
        evaluation of ``data`` (a live view, updated by later steps; ``.copy()`` keeps a snapshot)."""
        work = self._work.get(data)
        return work.diag if work is not None else Diagnostics.zeros(len(self.body_ids))

    @property
    def terrain(self) -> Terrain:
        """The free surface; may be replaced between steps."""
        return self._terrain

    @terrain.setter
    def terrain(self, value: Terrain) -> None:
        self._terrain = value
        self._max_height = float(value.max_height)
        if self._backend_request is not None:
            self._select_backend()

    @property
    def backend(self) -> str:
        """The kernel in use: "numba" (:mod:`rft_mujoco.compiled.elements`) or "numpy" (:mod:`rft_mujoco.physics.elements`)."""
        return "numpy" if self._fast is None else "numba"

    def _select_backend(self) -> None:
        request, terrain = self._backend_request, self._terrain
        spec = fastkernel.terrain_spec(terrain) if fastkernel.AVAILABLE and request != "numpy" else None
        if request == "numba" and not fastkernel.AVAILABLE:
            raise ValueError(f"backend='numba' needs numba, which failed to import ({fastkernel.IMPORT_ERROR}); "
                             "use backend='auto' or 'numpy'")
        if request == "numba" and spec is None:
            raise ValueError("backend='numba' supports FlatSurface, HeightfieldSurface and SandRegion "
                             f"terrains, got {type(terrain).__name__}; use backend='auto' (numpy for this "
                             "terrain) or 'numpy'")
        self._fast = None
        if spec is None:
            return
        try:
            fastkernel.ensure_compiled()
        except Exception as exc:  # a broken numba/LLVM install must not break the simulation
            if request == "numba":
                raise
            warnings.warn(f"rft_mujoco: the numba kernel failed to compile ({type(exc).__name__}: {exc}); "
                          "using the numpy kernel (slower). Pass backend='numpy' to silence this.",
                          RuntimeWarning, stacklevel=3)
            return
        kind, tp, heights = spec
        if getattr(self, "_packed", None) is None:
            self._packed = fastkernel.pack(self.local_centroids, self.local_normals, self.areas, self.elem_body,
                                           len(self.body_ids), self.elem_octant)
        self._fast = (self._packed.arrays(), kind, tp, heights)

    def __enter__(self) -> "SandHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.detach()

    def __repr__(self) -> str:
        return (f"SandHandle(media={self.media.name!r}, bodies={self.body_names}, "
                f"elements={self.n_elements}, element_size={self.element_size} m, backend={self.backend!r}, "
                f"attached={self.attached})")

    # --- per evaluation -----------------------------------------------------------------------------
    def _workspace(self, data) -> _Workspace:
        work = self._work.get(data)
        if work is None:
            work = self._work[data] = _Workspace(len(self.body_ids), self._fast is not None)
        return work

    def _evaluate(self, data, user_xfrc: np.ndarray, sand_out: np.ndarray) -> bool:
        """Add this handle's wrenches (nbody, 6) into ``sand_out``; True when any of them is non-zero."""
        self._evaluations[0] += 1
        work = self._workspace(data)
        g_hat = self._gravity()
        dt = self._opt.timestep
        lagged = work.follow_time(data.time, dt)
        diag = work.diag
        # 1. Broadphase and depth pre-pass: the bodies with at least one submerged element.
        touch = self._touching_fast(data, g_hat, work) if self._fast is not None else \
            self._touching_numpy(data, g_hat, work)
        if touch.size == 0:
            if not work.clean:
                diag.clear()
                work.clean = True
            return False
        work.clean = False
        k = touch.size
        if self.stabilize and self._fast is not None and self._compiled_rest():
            status = self._evaluate_rest_fast(data, user_xfrc, work, touch, dt, g_hat, lagged, sand_out)
        elif self.stabilize:
            status = self._evaluate_rest(data, user_xfrc, work, touch, dt, g_hat, lagged, sand_out)
        else:
            status = self._evaluate_naive(work, touch, g_hat, sand_out)
        if status < 0:
            self._raise_not_finite(diag, touch)
        if self.monitor is not None and self._evaluations[0] % self.monitor.every == 0:
            self.monitor.check(self, data, touch, work.v_com[:k], work.omega[:k], work.max_depth[:k])
        return bool(status)

    def _evaluate_naive(self, work, touch, g_hat, sand_out) -> int:
        """``stabilize=False``: the published force at each element's velocity (``passive``: a body's
        wrench is dropped when it would do positive work). Returns the status of :meth:`_commit`."""
        k = touch.size
        v_com, omega = work.v_com[:k], work.omega[:k]
        wrench, count, max_depth = self._rft(work, touch, v_com, omega, g_hat)
        applied = wrench.copy()
        if self.passive:
            power = np.einsum("ij,ij->i", wrench[:, :3], v_com) + np.einsum("ij,ij->i", wrench[:, 3:], omega)
            applied[power > 0.0] = 0.0
        return self._commit(work.diag, touch, applied, wrench, count, max_depth, np.zeros(k, dtype=bool),
                            sand_out)

    def _rft(self, work, touch, v_com, omega, g_hat):
        """RFT wrenches (k, 6) about each touching body's COM for body twists (v_com, omega) (k, 3), with
        the submerged leading element counts (k,) and deepest loaded depths (k,) m."""
        k = touch.size
        media, guards = self._media, self.guards
        if self._fast is not None:
            arrays, kind, tp, heights = self._fast
            fastkernel.wrenches(
                touch, k, *arrays, work.body_pos, work.body_mat, work.body_com, np.ascontiguousarray(v_com),
                np.ascontiguousarray(omega), _NO_ROWS, 0.0, g_hat, self._max_height, kind, tp, heights,
                media.xi_n_at(self._g_mag), law.COEFFICIENTS, media.mu_surf, guards.no_tension,
                guards.no_forward_tangential, guards.no_positive_power, self._tol, work.scratch, work.groups,
                work.count, work.max_depth)
            return work.groups[:k].sum(axis=1), work.count[:k].copy(), work.max_depth[:k].copy()
        sel = np.concatenate([np.arange(self._elem_slices[i], self._elem_slices[i + 1]) for i in touch])
        remap = np.empty(len(self.body_ids), dtype=np.int64)
        remap[touch] = np.arange(k)
        groups, count, max_depth = kernel.body_wrenches(
            self.local_centroids[sel], self.local_normals[sel], self.areas[sel], remap[self.elem_body[sel]],
            k, work.body_pos[:k], work.body_mat[:k].reshape(k, 3, 3), work.body_com[:k], v_com, omega,
            self.terrain, g_hat, self._gravity_vec, media, guards)
        work.max_depth[:k] = max_depth
        return groups.sum(axis=1), count, max_depth

    def _evaluate_rest(self, data, user_xfrc, work, touch, dt, g_hat, lagged, sand_out) -> int:
        """The rest treatment (:mod:`rft_mujoco.physics.rest`) of the touching bodies, in numpy (the reference of
        :mod:`rft_mujoco.compiled.rest`). Returns the status of :meth:`_commit`."""
        m, grp = self.model, self.groups
        k = touch.size
        group_of = grp.of_body[touch]                      # (k,) group of each touching body
        active = np.unique(group_of)                       # (G,) touching groups
        slot = np.searchsorted(active, group_of)           # (k,) row of each body's group in ``active``
        ref = self.body_ids[grp.ref[active]]               # (G,) MuJoCo ids of the reference bodies
        radius = grp.radius[active]
        jac, free, twist = self._free_twists(data, user_xfrc, ref, dt, lagged)
        # Element motions of the blended twists, at each touching body's COM.
        u = rest.blend(twist, free, radius)
        arm = work.body_com[:k] - data.xipos[ref[slot]]    # (k, 3) reference point -> body COM
        omega = u[slot, 3:]
        v_com = u[slot, :3] + np.cross(omega, arm)
        wrench, count, max_depth = self._rft(work, touch, v_com, omega, g_hat)
        # The groups' RFT wrenches at their reference points, their mobility, the rest wrenches.
        rft_g = np.zeros((active.size, 6))
        np.add.at(rft_g, slot, np.hstack([wrench[:, :3], wrench[:, 3:] + np.cross(arm, wrench[:, :3])]))
        flat = jac.reshape(-1, m.nv)
        minv_jt = np.empty_like(flat)
        mujoco.mj_solveM(m, data, minv_jt, flat)
        applied_g, resting_g = rest.rest_wrenches(free, flat @ minv_jt.T, rft_g, u, radius, dt)
        applied = _share(applied_g, rft_g, resting_g, wrench, slot, arm, radius)
        return self._commit(work.diag, touch, applied, wrench, count, max_depth, resting_g[slot], sand_out)

    def _compiled_rest(self) -> bool:
        """Whether the compiled rest evaluation reads MuJoCo's mass-matrix factor correctly (checked once)."""
        if self._layout_ok is None:
            self._layout_ok = fastrest.check_layout(self.model, mujoco.MjData(self.model))
            if not self._layout_ok:
                warnings.warn("rft_mujoco: MuJoCo's mass-matrix factor (qLD) is not laid out as this version "
                              f"of rft_mujoco reads it (mujoco {mujoco.__version__}); the rest treatment runs "
                              "in numpy (same forces, slower). Install the mujoco version of pyproject.toml.",
                              RuntimeWarning, stacklevel=4)
        return self._layout_ok

    def _evaluate_rest_fast(self, data, user_xfrc, work, touch, dt, g_hat, lagged, sand_out) -> int:
        """:meth:`_evaluate_rest` compiled (:func:`rft_mujoco.compiled.rest.evaluate`)."""
        m, grp, media, guards, diag = self.model, self.groups, self._media, self.guards, work.diag
        mujoco.mj_fwdActuation(m, data)
        if work.fast is None:
            work.fast = fastrest.Buffers(len(self.body_ids), grp.ref.size, m.nv)
        arrays, kind, tp, heights = self._fast
        status = fastrest.evaluate(
            touch, touch.size, self.body_ids, grp.of_body, grp.ref, grp.radius, self._bound_radius, data.xipos,
            data.cdof, data.subtree_com, data.qvel, data.qfrc_passive, data.qfrc_bias, data.qfrc_actuator,
            data.qfrc_applied, data.qfrc_constraint, data.qLD, data.qLDiagInv, *self._tree, user_xfrc, lagged, dt,
            *arrays, work.body_pos, work.body_mat, work.body_com, work.v_com, work.omega, g_hat, self._max_height,
            kind, tp, heights, media.xi_n_at(self._g_mag), law.COEFFICIENTS, media.mu_surf, guards.no_tension,
            guards.no_forward_tangential, guards.no_positive_power, self._tol, self._settings, work.scratch,
            work.groups, work.count, work.max_depth, *work.fast.arrays(), diag.force, diag.torque,
            diag.submerged, diag.max_depth, diag.scale, diag.rft_force, diag.resting, sand_out)
        if status == fastrest.BAD_ACCELERATION:
            self._free_twists(data, user_xfrc, self.body_ids[grp.ref], dt, lagged)   # raises, naming the bodies
        return status

    def _free_twists(self, data, user_xfrc, ref, dt, lagged):
        """Jacobians (G, 6, nv) of the reference bodies' COMs, their free twists (G, 6) at the end of the step
        without sand, and their twists now (G, 6).

        The free acceleration uses the smooth forces of this evaluation (passive, bias, actuators, applied,
        the user's xfrc_applied) plus, when ``lagged``, the constraint forces of MuJoCo's previous solve.
        """
        m = self.model
        jac = np.empty((ref.size, 6, m.nv))
        for i, b in enumerate(ref):
            mujoco.mj_jacBodyCom(m, data, self._jacp, self._jacr, int(b))
            jac[i, :3] = self._jacp
            jac[i, 3:] = self._jacr
        mujoco.mj_fwdActuation(m, data)
        qfrc = data.qfrc_passive - data.qfrc_bias + data.qfrc_actuator + data.qfrc_applied
        if lagged:
            qfrc = qfrc + data.qfrc_constraint
        for b in np.flatnonzero(np.any(user_xfrc[1:] != 0.0, axis=1)) + 1:
            mujoco.mj_applyFT(m, data, user_xfrc[b, :3].copy(), user_xfrc[b, 3:].copy(), data.xipos[b].copy(),
                              int(b), qfrc)
        qacc = np.empty(m.nv)
        mujoco.mj_solveM(m, data, qacc.reshape(1, -1), qfrc.reshape(1, -1))
        if not np.all(np.isfinite(qacc)):
            names = [m.body(int(b)).name for b in ref]
            raise FloatingPointError(
                f"non-finite acceleration without sand while computing sand forces on bodies {names}: "
                "data.ctrl, data.qfrc_applied or data.xfrc_applied holds NaN/inf (or the model's "
                "actuators produce it); fix the input before stepping")
        twist = jac @ data.qvel
        return jac, twist + dt * (jac @ qacc), twist

    def _commit(self, diag, touch, applied, rft, count, max_depth, resting, sand_out) -> int:
        """Diagnostics of the touching bodies and ``applied`` (k, 6) into ``sand_out``. Returns 1 when a
        wrench is non-zero, 0 when none is, -1 (``sand_out`` untouched) when one is not finite."""
        diag.clear()
        radius = self._bound_radius[touch][:, None]
        rft_norm = np.linalg.norm(np.hstack([rft[:, :3], rft[:, 3:] / radius]), axis=1)
        app_norm = np.linalg.norm(np.hstack([applied[:, :3], applied[:, 3:] / radius]), axis=1)
        loaded = rft_norm > 0.0
        diag.force[touch] = applied[:, :3]
        diag.torque[touch] = applied[:, 3:]
        diag.rft_force[touch] = rft[:, :3]
        diag.submerged[touch] = count
        diag.max_depth[touch] = max_depth
        diag.scale[touch[loaded]] = app_norm[loaded] / rft_norm[loaded]
        diag.resting[touch] = resting & loaded
        if not np.all(np.isfinite(applied)):
            return -1
        np.add.at(sand_out, self.body_ids[touch], applied)
        return int(np.any(applied != 0.0))

    def _gravity(self) -> np.ndarray:
        """Unit gravity direction (3,), recomputed only when ``model.opt.gravity`` changed."""
        g = self._opt_gravity.tolist()
        if g != self._gravity_seen:
            g_hat, self._g_mag = gravity_direction(g)
            self._g_hat = np.ascontiguousarray(g_hat)
            self._gravity_vec = np.array(g)
            self._gravity_seen = g
        return self._g_hat

    def _touching_fast(self, data, g_hat, work) -> np.ndarray:
        """Compiled :meth:`_touching_numpy` (same result) straight from the MjData arrays."""
        arrays, kind, tp, heights = self._fast
        if not self._fast_touching_ok(g_hat):         # tilted gravity on a heightfield: numpy explains
            return self._touching_numpy(data, g_hat, work)
        p = self._packed
        k = fastkernel.touching(self.body_ids, self._root, data.xpos, data.xmat, data.xipos, data.cvel,
                                data.subtree_com, data.qpos, data.qvel, self._bound_center, self._bound_radius,
                                p.centroids, p.cluster_start, p.cluster_center, p.cluster_radius,
                                p.body_clusters, g_hat, self._max_height, kind, tp, heights, work.touch,
                                work.body_pos, work.body_mat, work.body_com, work.v_com, work.omega)
        if k < 0:
            return self._touching_numpy(data, g_hat, work)  # raises the non-finite state error
        return work.touch[:k]

    def _fast_touching_ok(self, g_hat) -> bool:
        """Whether the compiled broadphase handles this terrain and gravity (not: tilted gravity on a
        heightfield, which the numpy pre-pass explains)."""
        _, kind, tp, _ = self._fast
        return (kind == fastkernel.FLAT and tp[6] == 0.0) or g_hat[2] <= -1.0 + tol.VERTICAL_GRAVITY_TOL

    def _touching_numpy(self, data, g_hat, work) -> np.ndarray:
        """Numpy broadphase and depth pre-pass: indices (k,) into ``body_ids`` of the bodies with a
        submerged element; fills rows 0..k-1 of the workspace's pose and velocity buffers."""
        ids = self.body_ids
        xmat = data.xmat[ids].reshape(-1, 3, 3)
        centers = data.xpos[ids] + np.einsum("bij,bj->bi", xmat, self._bound_center)
        low = -(centers @ g_hat) - self._bound_radius
        cand = np.flatnonzero(low < self.terrain.max_height)
        if cand.size == 0:
            return cand
        if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
            bad = [self.body_names[i] for i in cand]
            raise FloatingPointError(
                f"non-finite qpos/qvel while computing sand forces on bodies {bad}: the simulation already "
                "diverged (check timestep, actuator gains and masses; keep stabilize=True)")
        sel = np.concatenate([np.arange(self._elem_slices[i], self._elem_slices[i + 1]) for i in cand])
        remap = np.empty(len(ids), dtype=np.int64)
        remap[cand] = np.arange(cand.size)
        b = remap[self.elem_body[sel]]
        pos = data.xpos[ids[cand]][b] + np.einsum("eij,ej->ei", xmat[cand][b], self.local_centroids[sel])
        hit = np.bincount(b, weights=self.terrain.depth(pos, g_hat) > 0.0, minlength=cand.size) > 0
        touch = cand[hit]
        k, bids = touch.size, ids[touch]
        work.body_pos[:k] = data.xpos[bids]
        work.body_mat[:k] = data.xmat[bids]
        work.body_com[:k] = data.xipos[bids]
        omega = work.omega[:k]
        omega[:] = data.cvel[bids, :3]
        work.v_com[:k] = data.cvel[bids, 3:] + np.cross(omega, data.xipos[bids] - data.subtree_com[
            self._root[touch]])
        return touch

    def _raise_not_finite(self, diag, touch) -> None:
        bad = [self.body_names[i] for i in touch
               if not (np.all(np.isfinite(diag.force[i])) and np.all(np.isfinite(diag.torque[i])))]
        raise FloatingPointError(f"non-finite sand wrench on bodies {bad}; nothing was written to "
                                 "xfrc_applied. Check the model's inputs (ctrl, qfrc_applied, "
                                 "xfrc_applied, masses) for NaN/inf")


_NO_ROWS = np.zeros((0, 6))
"""Empty (0, 6) float array: "no predicted accelerations" for the compiled element kernel."""


def _share(applied_g, rft_g, resting_g, rft, slot, arm, radius) -> np.ndarray:
    """Each touching body's part (k, 6) of its group's wrench (about the body's COM).

    A group in flow gives each body its own RFT wrench times the group's factor; a resting group's rest
    wrench is shared in proportion to the bodies' RFT wrenches (torques over the group radius), with the
    torque chosen so that the parts add up to the group's wrench about its reference point. The bodies of
    a group are welded together, so the split changes the diagnostics only, never the motion.
    """
    k = slot.size
    out = np.zeros((k, 6))
    r = radius[slot][:, None]
    size = np.linalg.norm(np.hstack([rft[:, :3], rft[:, 3:] / r]), axis=1)
    total = np.bincount(slot, weights=size, minlength=rft_g.shape[0])
    g_norm = np.linalg.norm(np.hstack([rft_g[:, :3], rft_g[:, 3:] / radius[:, None]]), axis=1)
    a_norm = np.linalg.norm(np.hstack([applied_g[:, :3], applied_g[:, 3:] / radius[:, None]]), axis=1)
    for j in range(k):
        g = slot[j]
        if total[g] <= 0.0:
            continue
        if not resting_g[g]:
            out[j] = rft[j] * (a_norm[g] / g_norm[g] if g_norm[g] > 0.0 else 0.0)
            continue
        share = size[j] / total[g]
        out[j, :3] = share * applied_g[g, :3]
    for g in np.flatnonzero(resting_g):
        mine = np.flatnonzero(slot == g)
        moment = applied_g[g, 3:] - np.cross(arm[mine], out[mine, :3]).sum(axis=0)
        out[mine, 3:] = (size[mine] / total[g])[:, None] * moment[None, :] if total[g] > 0.0 else 0.0
    return out


def attach(model, media: Media | str, bodies: Sequence[str | int] | None = None,
           surface_height: float | Terrain = 0.0, resolution: str | float = "default", *,
           guards: Guards = PUBLISHED, stabilize: bool = True, passive: bool = True,
           monitor: bool | ValidityMonitor = True, backend: str = "auto", rk4_stages: str = "all") -> SandHandle:
    """Attach 3D-RFT sand to ``model``: from now on ``mujoco.mj_step(model, data)`` includes it.

    Args:
        model: the MjModel.
        media: a :class:`Media` or a preset name (see ``rft_mujoco.PRESETS``).
        bodies: body names (or ids) whose geoms touch the sand; None means every body but the world.
        surface_height: a flat free surface height in m, or a terrain (:class:`FlatSurface`,
            :class:`HeightfieldSurface`, :class:`SandRegion`).
        resolution: element size: a preset name (``rft_mujoco.geometry.surface.RESOLUTIONS``) or metres.
        guards: clean-ups of the fit's artefacts (default none: the published law).
        stabilize: the rest treatment (default True, :mod:`rft_mujoco.physics.rest`): a body the sand can hold is
            held at rest, whatever loads it (its own weight, a payload through a contact or weld, a joint
            or tendon limit), and the sand never adds kinetic energy in a step; a body in flow gets the
            published force (to ``(|dv| / v)^3`` above the speed change ``dv`` of one step). False applies
            the published force at every element's current velocity (the naive coupling: bodies chatter
            instead of resting).
        passive: with ``stabilize=False``, zero a body's wrench whenever it would do positive work.
        monitor: warn (:class:`rft_mujoco.RFTValidityWarning`, once per reason) when a loaded body leaves
            the quasi-static regime or the validated depth (:mod:`rft_mujoco.coupling.monitor`); a
            :class:`ValidityMonitor` to set the check interval; False switches it off.
        backend: "numba" (compiled, cached after the first use on a machine), "numpy" (the readable
            reference), or "auto" (default: numba when it imports and supports the terrain, else numpy).
            Both give the same forces to round-off.
        rk4_stages: with ``integrator="RK4"``, "all" (default) evaluates the sand at each of the four
            stages of a step; "first" evaluates it at the first stage (the state at the start of the step)
            and holds that wrench through stages 2-4, a quarter of the cost. It applies only while every
            handle of the model asks for it; other integrators evaluate once per step anyway.
    Returns:
        a :class:`SandHandle`; call ``handle.detach()`` (or use it as a context manager) to remove it.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    if rk4_stages not in RK4_STAGES:
        raise ValueError(f"rk4_stages must be one of {RK4_STAGES}, got {rk4_stages!r}")
    media = get_media(media)
    terrain = as_terrain(surface_height)
    size = surface.element_size(resolution)
    if bodies is None:
        ids = [b for b in range(1, model.nbody)
               if any(model.geom_bodyid[g] == b and model.geom_type[g] not in
                      (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)
                      for g in range(model.ngeom))]
    else:
        if isinstance(bodies, (str, int)):
            bodies = [bodies]
        ids = [_body_id(model, b) for b in bodies]
        if len(set(ids)) != len(ids):
            raise ValueError(f"bodies lists a body twice: {list(bodies)}")
    if not ids:
        raise ValueError("no bodies to attach sand to: the model has no body with surface geoms")
    gravity_direction(model.opt.gravity)  # raises on zero gravity
    handle = SandHandle(model, media, ids, terrain, size, guards, stabilize, passive, monitor, backend)
    handle.rk4_stages = rk4_stages
    DISPATCHER.register(handle)
    handle.attached = True
    return handle


def detach_all() -> None:
    """Detach every sand handle in the process (and restore the user's own control callback)."""
    for h in DISPATCHER.handles:
        h.detach()
