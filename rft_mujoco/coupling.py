"""MuJoCo coupling: attach 3D-RFT sand to bodies of a model; plain ``mujoco.mj_step`` then includes it.

Each physics evaluation (every integrator stage: once per step for Euler/implicitfast, four times for
RK4) the dispatcher calls :meth:`SandHandle._evaluate`, which

1. skips bodies whose bounding sphere is above the highest point of the sand (broadphase), and finds
   the bodies that touch the sand (an element with depth > 0); nothing else runs when none does (no
   Jacobians, no limiter, the diagnostics are zeroed once);
2. for the touching ones, takes element positions, normals and velocities from ``xpos``/``xmat``/``cvel``
   (``cvel``'s linear part refers to ``subtree_com`` of the root, converted to each body's COM);
3. computes the RFT force of every submerged leading element and the wrench about the body's COM
   (``xipos``, where ``xfrc_applied`` acts);
4. with ``stabilize=True`` (default), regularizes low speeds: the motion direction is blended with the
   predicted one below ``|a_free| dt``, and below the speed change of one full RFT impulse
   (``|F_rft| dt / m``) the octant wrenches are scaled (and mixed with the RFT resistances to the motion
   left after the step) to minimize the kinetic energy after the step, so the sand can stop a body but
   never reverse or accelerate it, and bodies come to exact rest. Above both speeds the published force
   is applied unchanged unless it would add energy (see :meth:`SandHandle._limit`,
   :func:`rft_mujoco.kernel.limit_impulses` and :mod:`rft_mujoco.stability` for the measurements);
5. adds the wrenches to ``data.xfrc_applied`` on top of the user's own wrench;
6. every ``monitor.every`` evaluations, checks the loaded bodies against the validity range of 3D-RFT
   (:mod:`rft_mujoco.monitor`; ``attach(monitor=False)`` switches it off).

Steps 1-3 and the bookkeeping of 4-5 run in the numba-compiled kernels of :mod:`rft_mujoco.fastkernel`
(``attach(backend="numba")``, the default when numba imports and supports the terrain) on per-MjData
buffers, or in the numpy reference :mod:`rft_mujoco.kernel` (``backend="numpy"``); both give the same
wrenches to round-off (tests/test_fastkernel.py). With the numba backend, step 4 (Jacobians, free motion,
the impulse limiter) is compiled too (:mod:`rft_mujoco.fastlimit`, optionally warm-started from the previous
step; tests/test_fastlimit.py compares it with :meth:`SandHandle._limit`), and steps 1-5 are then one
native call per evaluation (:mod:`rft_mujoco.native`; ``handle.native = False`` calls the same compiled
functions through numba's dispatcher, tests/test_native.py checks they agree bit for bit). Costs are
measured by ``python -m rft_mujoco bench``.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
import weakref
from collections.abc import Sequence

import mujoco
import numpy as np

from . import fastkernel, fastlimit, kernel, native, surface
from .monitor import ValidityMonitor
from ._dispatch import DISPATCHER
from . import law
from .law import PUBLISHED, Guards, gravity_direction
from .media import Media, get_media
from .terrain import Terrain, as_terrain


@dataclasses.dataclass
class Diagnostics:
    """Per-body sand state of the latest evaluation of one MjData (arrays over ``SandHandle.body_ids``).

    Attributes:
        force: (B, 3) N, world frame, applied at each body's COM.
        torque: (B, 3) N m, world frame, about each body's COM.
        submerged: (B,) int, number of submerged leading elements that carried stress.
        max_depth: (B,) m, deepest loaded element (0 when none).
        scale: (B,) the impulse-limiter factor applied to the RFT wrench (1 = full published force).
        rft_force: (B, 3) N, the RFT force before the impulse limiter.
    """

    force: np.ndarray
    torque: np.ndarray
    submerged: np.ndarray
    max_depth: np.ndarray
    scale: np.ndarray
    rft_force: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> "Diagnostics":
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, dtype=np.int64), np.zeros(n),
                   np.ones(n), np.zeros((n, 3)))


def _clear(diag: Diagnostics) -> None:
    diag.force[:] = 0.0
    diag.torque[:] = 0.0
    diag.submerged[:] = 0
    diag.max_depth[:] = 0.0
    diag.scale[:] = 1.0
    diag.rft_force[:] = 0.0


def _follow_time(work: "_Workspace", t: float, dt: float) -> None:
    """The limiter's warm start carries over only while time runs on by at most one step (RK4 stages
    included): a reset or a jump in time starts cold, so rollouts from a reset are reproducible."""
    if not 0.0 <= t - work.last_time <= dt * (1.0 + 1e-9):
        work.warm_rounds[:] = 0
        work.warm[:] = 0.0
    work.last_time = t


def _nothing_touches(work: "_Workspace") -> None:
    """No body touches the sand: zero the diagnostics and the warm start, once."""
    if not work.clean:
        _clear(work.diag)
        work.warm_rounds[:] = 0
        work.warm[:] = 0.0
        work.clean = True


_NO_ROWS = np.zeros((0, 6))
"""Empty (0, 6) float array: "no accelerations" / "no limiter result" for the compiled kernel."""
RK4_STAGES = ("all", "first")
"""Values of ``attach(rk4_stages=...)``: evaluate the sand at every RK4 stage, or at the first and hold it."""
BACKENDS = ("auto", "numba", "numpy")
"""Kernel backends of :func:`attach`: numba-compiled (:mod:`rft_mujoco.fastkernel`) or numpy
(:mod:`rft_mujoco.kernel`, the readable reference); "auto" is numba when it imports and supports the
terrain, numpy otherwise."""


class _Workspace:
    """Per-MjData buffers of one handle (datas may be stepped in different threads): the diagnostics,
    and rows 0..k-1 of the touching bodies' poses, velocities and octant wrenches."""

    __slots__ = ("diag", "touch", "body_pos", "body_mat", "body_com", "v_com", "omega", "groups",
                 "count", "max_depth", "col_groups", "col_count", "col_max_depth", "scratch", "col_v", "col_w",
                 "jac", "qacc", "minv", "eye", "limited", "warm", "warm_rounds", "arena", "iarena", "state", "args",
                 "native")

    def __init__(self, n_bodies: int, compiled: bool, nv: int, rest_columns: int) -> None:
        b = n_bodies
        self.diag = Diagnostics.zeros(b)
        # (clean, last time s) in one array, read and written by the native route as well.
        self.state = np.array([1.0, -math.inf])
        self.touch = np.zeros(b, dtype=np.int64)
        self.body_pos, self.body_com, self.v_com, self.omega = (np.zeros((b, 3)) for _ in range(4))
        self.body_mat = np.zeros((b, 9))
        self.groups = np.zeros((b, kernel.GROUPS_PER_BODY, 6))
        self.count = np.zeros(b, dtype=np.int64)
        self.max_depth = np.zeros(b)
        self.col_groups = np.zeros((b, kernel.GROUPS_PER_BODY, 6))
        self.col_count = np.zeros(b, dtype=np.int64)
        self.col_max_depth = np.zeros(b)
        self.scratch = np.zeros((fastkernel.SCRATCH_ROWS, fastkernel.CLUSTER_SIZE)) if compiled else None
        # The compiled stabilized path (fastlimit): Jacobians, free acceleration, M^-1, limiter output and
        # the previous evaluation's limiter factors (its warm start).
        self.col_v, self.col_w = np.zeros((b, 3)), np.zeros((b, 3))
        self.jac = np.zeros((b, 6, nv))
        self.qacc = np.zeros(nv)
        self.minv = np.zeros((nv, nv))
        self.eye = np.eye(nv)
        self.limited = np.zeros((b, 6))
        r = rest_columns
        self.warm = np.zeros((b, kernel.GROUPS_PER_BODY, r, r))
        self.warm_rounds = np.zeros(b, dtype=np.int64)
        # every other working array of the compiled stabilized evaluation, carved per call (fastlimit)
        n_float, n_int = fastlimit.arena_sizes(b, nv, r) if compiled else (0, 0)
        self.arena = np.zeros(n_float)
        self.iarena = np.zeros(n_int, dtype=np.int64)
        self.args = None            # the compiled calls' fixed arguments (SandHandle._fixed_args)
        self.native = None          # the native call's argument table (SandHandle._native_table)

    clean = native.Slot("state", 0, bool, "Whether the diagnostics and the warm start are already zero.")
    last_time = native.Slot("state", 1, float, "The time of the last evaluation, s (warm-start continuity).")


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
    """

    _ROUTED = frozenset({"native", "stabilize", "passive", "compiled_limiter", "warm_start", "guards", "monitor",
                         "rk4_stages", "attached", "_fast", "_max_height", "_media", "_g_addr"})
    """Attributes the dispatcher's native routes were built from: setting one rebuilds them."""

    def __setattr__(self, name, value) -> None:
        object.__setattr__(self, name, value)
        if name in SandHandle._ROUTED:
            DISPATCHER.invalidate()

    def __init__(self, model, media: Media, body_ids: Sequence[int], terrain: Terrain, size: float,
                 guards: Guards, stabilize: bool, passive: bool, monitor: bool | ValidityMonitor = True,
                 backend: str = "auto"):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self._backend_request = None
        self._counts = np.zeros(2, dtype=np.int64)       # evaluations, monitor period (the native route's)
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
        self._elem_slices = np.concatenate([[0], np.cumsum(counts)])
        self.elem_octant = kernel.octants(self.local_centroids, self._bound_center[self.elem_body])
        self._work: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
        self._root = model.body_rootid[self.body_ids]
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self.attached = False
        self.evaluations = 0
        self.monitor = (monitor if isinstance(monitor, ValidityMonitor) else
                        ValidityMonitor() if monitor else None)
        self._replaced: list[tuple[int, int, int]] = []
        # Per-evaluation constants and the compiled kernel's inputs.
        self._elem_slices = np.ascontiguousarray(self._elem_slices, dtype=np.int64)
        self._root64 = np.ascontiguousarray(self._root, dtype=np.int64)
        self._opt = model.opt
        self._opt_gravity = model.opt.gravity            # a live view: gravity changes are seen
        self._gravity_seen = None
        self._fast_checked = None
        self._fast_seen = None
        self._tol = fastkernel.tolerances()
        self._solver = fastlimit.solver_settings()
        self._tree = tuple(np.ascontiguousarray(a, dtype=np.int64) for a in (
            model.body_rootid, model.body_dofnum, model.body_dofadr, model.body_parentid, model.dof_parentid))
        self.warm_start = False
        """Compiled stabilized path: start the limiter from the previous evaluation's factors (False: from
        the published force every time, as the numpy reference does); see :func:`attach`."""
        self.rk4_stages = "all"
        """With integrator="RK4": "all" evaluates at every stage, "first" holds the first stage's wrench
        (see :func:`attach`)."""
        self.native = True
        """With the numba backend and stabilize=True: make the whole evaluation one native call
        (:mod:`rft_mujoco.native`, same results, no numba dispatch); False uses numba's dispatcher (the
        tests compare the two). Ignored where :func:`rft_mujoco.native.available` is False."""
        self.compiled_limiter = True
        """With the numba backend and stabilize=True: the free motion and the limiter run compiled
        (:mod:`rft_mujoco.fastlimit`); False runs :meth:`_free_motion` and :meth:`_limit` in numpy around
        the compiled kernels (the reference the tests compare with)."""
        self._backend_request = backend
        self._select_backend()

    # --- public -------------------------------------------------------------------------------------
    evaluations = native.Slot("_counts", 0, int, "Sand evaluations so far (all MjData together).")

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
        """Per-body force, torque, submerged element count and max depth of the latest evaluation."""
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
        """The kernel in use: "numba" (:mod:`rft_mujoco.fastkernel`) or "numpy" (:mod:`rft_mujoco.kernel`)."""
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
    def _evaluate(self, data, user_xfrc: np.ndarray, sand_out: np.ndarray, addresses=None) -> bool:
        """Add this handle's wrenches (nbody, 6) into ``sand_out``; True when any of them is non-zero.
        ``addresses``: (address of user_xfrc, of sand_out) when the caller knows them (the native call)."""
        self._counts[0] += 1
        work = self._work.get(data)
        if work is None:
            work = self._work[data] = _Workspace(len(self.body_ids), self._fast is not None, self.model.nv,
                                                 int(self._solver[4]))
        g_hat = self._gravity()
        if self._takes_native_call(g_hat):
            return self._evaluate_native(data, work, user_xfrc, sand_out, addresses)
        diag = work.diag
        # 1. Broadphase and depth pre-pass: the bodies with at least one submerged element.
        touch = self._touching_fast(data, g_hat, work) if self._fast is not None else \
            self._touching_numpy(data, g_hat, work)
        if touch.size == 0:
            _nothing_touches(work)
            return False
        work.clean = False
        k = touch.size
        v_com, omega = work.v_com[:k], work.omega[:k]
        dt = self._opt.timestep
        if self.stabilize and self._fast is not None and self.compiled_limiter:
            # 2-5 compiled in one call: free motion, RFT octant wrenches, impulse limiter, diagnostics and
            # the wrenches into sand_out (fastlimit.stabilized).
            status = self._stabilized_fast(data, user_xfrc, work, touch, dt, g_hat, sand_out)
            max_depth = work.max_depth[:k]
        else:
            status, max_depth = self._evaluate_steps(data, user_xfrc, work, touch, dt, g_hat, sand_out)
        if status < 0:
            self._raise_not_finite(diag, touch)
        if self.monitor is not None and self._counts[0] % self.monitor.every == 0:
            self.monitor.check(self, data, touch, v_com, omega, max_depth)
        return bool(status)

    def _evaluate_steps(self, data, user_xfrc, work, touch, dt, g_hat, sand_out):
        """Steps 2-5 of :meth:`_evaluate` with the numpy limiter (around the numpy or the compiled kernels).
        Returns (status of :func:`fastkernel.finish`, max depths (k,))."""
        k = touch.size
        diag = work.diag
        v_com, omega = work.v_com[:k], work.omega[:k]
        acc = None
        limited = None
        if self.stabilize:
            jac, qvel_pred, qacc_free = self._free_motion(data, self.body_ids[touch], user_xfrc, dt)
            acc = jac @ qacc_free                      # (k, 6): [linear at COM, angular]
        # 2. RFT octant wrenches (k, 8, 6) of the touching bodies.
        groups, count, max_depth, loaded = self._wrenches(work, touch, v_com, omega, acc, dt, g_hat,
                                                          work.groups, work.count, work.max_depth)
        # 3. Impulse limiter (stabilize) and diagnostics.
        if loaded and self.stabilize:
            def column(v_lin, v_ang):
                # RFT octant wrenches (k, 8, 6) for the element motions of body twists (no blend).
                return self._wrenches(work, touch, np.ascontiguousarray(v_lin), np.ascontiguousarray(v_ang),
                                      None, 0.0, g_hat, work.col_groups, work.col_count,
                                      work.col_max_depth)[0].copy()
            limited = self._limit(data, jac, groups, qvel_pred, dt, self._bound_radius[touch], column)
        if self._fast is not None:
            status = fastkernel.finish(groups, count, max_depth, v_com, omega,
                                       _NO_ROWS if limited is None else np.ascontiguousarray(limited),
                                       self.passive and not self.stabilize, touch, k, self.body_ids,
                                       diag.force, diag.torque, diag.submerged, diag.max_depth, diag.scale,
                                       diag.rft_force, sand_out)
        else:
            status = self._finish_numpy(diag, groups, count, max_depth, v_com, omega, limited, touch,
                                        sand_out)
        return status, max_depth

    def _gravity(self) -> np.ndarray:
        """Unit gravity direction (3,), recomputed only when ``model.opt.gravity`` changed."""
        g = self._opt_gravity.tolist()
        if g != self._gravity_seen:
            g_hat, self._g_mag = gravity_direction(g)
            self._g_hat = np.ascontiguousarray(g_hat)
            self._g_addr = self._g_hat.ctypes.data
            self._gravity_vec = np.array(g)
            self._gravity_seen = g
        return self._g_hat

    def _stabilized_fast(self, data, user_xfrc, work, touch, dt, g_hat, sand_out) -> int:
        """Steps 2-5 of the stabilized evaluation in one compiled call (:func:`fastlimit.stabilized`): the
        same as :meth:`_evaluate_steps` with :meth:`_free_motion`, :meth:`_wrenches`, :meth:`_limit` and
        :func:`fastkernel.finish`, the limiter warm-started from the previous evaluation
        (``self.warm_start``). Returns the status of :func:`fastkernel.finish`."""
        m = self.model
        a = work.args or self._fixed_args(data, work)
        _follow_time(work, data.time, dt)
        mujoco.mj_fwdActuation(m, data)
        if m.nv:
            mujoco.mj_solveM(m, data, work.minv, work.eye)
        _, kind, tp, heights = self._fast
        media, guards = self._media, self.guards
        status = fastlimit.stabilized(
            touch, touch.size, self.body_ids, user_xfrc, *a[2], dt, *a[3], self.warm_start, *a[4], g_hat,
            self._max_height, kind, tp, heights, media.xi_n_at(self._g_mag), law.COEFFICIENTS, media.mu_surf,
            guards.no_tension, guards.no_forward_tangential, guards.no_positive_power, self._tol, *a[5], sand_out)
        if status == fastlimit.BAD_ACCELERATION:
            self._free_motion(data, self.body_ids[touch], user_xfrc, dt)   # raises, naming the bodies
        return status

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

    def _call_arrays(self, data, work) -> dict:
        """Every array the compiled calls read or write, by the argument names of
        :data:`rft_mujoco.native.FIELDS`: MjData's, the handle's and the workspace's."""
        _, _, tp, heights = self._fast
        packed, diag = self._packed, work.diag
        return dict(
            xpos=data.xpos, xmat=data.xmat, xipos=data.xipos, cvel=data.cvel, subtree_com=data.subtree_com,
            qpos=data.qpos, qvel=data.qvel, cdof=data.cdof, qfrc_passive=data.qfrc_passive,
            qfrc_bias=data.qfrc_bias, qfrc_actuator=data.qfrc_actuator, qfrc_applied=data.qfrc_applied,
            ids=self.body_ids, root=self._root64, bound_center=self._bound_center, bound_radius=self._bound_radius,
            body_rootid=self._tree[0], body_dofnum=self._tree[1], body_dofadr=self._tree[2],
            body_parentid=self._tree[3], dof_parentid=self._tree[4], settings=self._solver,
            centroids=packed.centroids, normals=packed.normals, areas=packed.areas,
            cluster_start=packed.cluster_start, cluster_octant=packed.cluster_octant,
            cluster_center=packed.cluster_center, cluster_radius=packed.cluster_radius,
            body_clusters=packed.body_clusters, tp=tp, heights=heights, coef=law.COEFFICIENTS, tol=self._tol,
            touch=work.touch, body_pos=work.body_pos, body_mat=work.body_mat, body_com=work.body_com,
            v_com=work.v_com, omega=work.omega, minv=work.minv, eye=work.eye, warm=work.warm,
            warm_rounds=work.warm_rounds, scratch=work.scratch, groups=work.groups, count=work.count,
            max_depth=work.max_depth, col_v=work.col_v, col_w=work.col_w, col_groups=work.col_groups,
            col_count=work.col_count, col_max_depth=work.col_max_depth, jac=work.jac, qacc=work.qacc,
            limited=work.limited, force=diag.force, torque=diag.torque, submerged=diag.submerged,
            depth_max=diag.max_depth, scale=diag.scale, rft_force=diag.rft_force, arena=work.arena,
            iarena=work.iarena)

    # The argument runs of the dispatched calls (fastkernel.touching, fastlimit.stabilized) between their
    # per-call arguments, in signature order.
    _ARG_RUNS = (
        ("ids", "root", "xpos", "xmat", "xipos", "cvel", "subtree_com", "qpos", "qvel", "bound_center",
         "bound_radius", "centroids", "cluster_start", "cluster_center", "cluster_radius", "body_clusters"),
        ("touch", "body_pos", "body_mat", "body_com", "v_com", "omega"),
        ("xipos", "cdof", "subtree_com", "qvel", "qfrc_passive", "qfrc_bias", "qfrc_actuator", "qfrc_applied",
         "minv", "body_rootid", "body_dofnum", "body_dofadr", "body_parentid", "dof_parentid"),
        ("bound_radius", "warm", "warm_rounds"),
        ("settings", "centroids", "normals", "areas", "cluster_start", "cluster_octant", "cluster_center",
         "cluster_radius", "body_clusters", "body_pos", "body_mat", "body_com", "v_com", "omega"),
        ("scratch", "groups", "count", "max_depth", "col_v", "col_w", "col_groups", "col_count",
         "col_max_depth", "jac", "qacc", "limited", "force", "torque", "submerged", "depth_max", "scale",
         "rft_force", "arena", "iarena"))

    def _fixed_args(self, data, work) -> tuple:
        """The arguments of the dispatched compiled calls that are the same at every evaluation of ``data``,
        built once per workspace: the runs of :attr:`_ARG_RUNS` (touching before g_hat, touching after
        heights, stabilized after user_xfrc, after dt, after warm_start, after tol)."""
        arrays = self._call_arrays(data, work)
        work.args = tuple(tuple(arrays[name] for name in run) for run in self._ARG_RUNS)
        return work.args

    def _takes_native_call(self, g_hat) -> bool:
        """Whether an evaluation is one native call (:meth:`_evaluate_native`; the route needs it of every
        handle of the model)."""
        return (self.native and self.stabilize and self.compiled_limiter and self._fast is not None
                and self._fast_touching_ok(g_hat) and native.available())

    def _fast_touching_ok(self, g_hat) -> bool:
        """Whether the compiled broadphase handles this terrain and gravity (not: tilted gravity on a
        heightfield, which the numpy pre-pass explains)."""
        if self._gravity_seen is not self._fast_checked or self._fast is not self._fast_seen:
            _, kind, tp, _ = self._fast
            self._fast_checked = self._gravity_seen
            self._fast_seen = self._fast
            self._fast_gravity_ok = (kind == fastkernel.FLAT and tp[6] == 0.0) or g_hat[2] <= -1.0 + 1e-9
        return self._fast_gravity_ok

    def _native_table(self, data, work) -> native.Table:
        """The native call's argument table for ``data`` (built once per workspace and terrain)."""
        return native.Table(self._call_arrays(data, work), self.model, data, self._fast[1], self._fast)

    def _evaluate_native(self, data, work, user_xfrc, sand_out, addresses) -> bool:
        """:meth:`_evaluate` for the compiled stabilized path as one native call (:mod:`rft_mujoco.native`):
        the same broadphase, MuJoCo calls and compiled evaluation as :meth:`_touching_fast` and
        :meth:`_stabilized_fast`, without numba's per-argument dispatch."""
        table = work.native
        if table is None or table.source is not self._fast:
            table = work.native = self._native_table(data, work)
        if addresses is None:
            addresses = (user_xfrc.ctypes.data, sand_out.ctypes.data)
        dt = self._opt.timestep
        _follow_time(work, data.time, dt)
        media = self._media
        code = native.entry()(table.address, addresses[0], addresses[1], self._g_addr, dt,
                              media.xi_n_at(self._g_mag), media.mu_surf, self._max_height,
                              native.flags(self.warm_start, self.guards))
        if code == native.NOT_FINITE_STATE:
            self._touching_numpy(data, self._g_hat, work)    # raises the non-finite state error
        k, status = native.decode(code)
        if k == 0:
            _nothing_touches(work)
            return False
        work.clean = False
        touch = work.touch[:k]
        if status == fastlimit.BAD_ACCELERATION:
            self._free_motion(data, self.body_ids[touch], user_xfrc, dt)   # raises, naming the bodies
        if status < 0:
            self._raise_not_finite(work.diag, touch)
        if self.monitor is not None and self._counts[0] % self.monitor.every == 0:
            self.monitor.check(self, data, touch, work.v_com[:k], work.omega[:k], work.max_depth[:k])
        return bool(status)

    def _raise_not_finite(self, diag, touch) -> None:
        bad = [self.body_names[i] for i in touch
               if not (np.all(np.isfinite(diag.force[i])) and np.all(np.isfinite(diag.torque[i])))]
        raise FloatingPointError(f"non-finite sand wrench on bodies {bad}; nothing was written to "
                                 "xfrc_applied. Check the model's inputs (ctrl, qfrc_applied, "
                                 "xfrc_applied, masses) for NaN/inf")

    def _touching_fast(self, data, g_hat, work) -> np.ndarray:
        """Compiled :meth:`_touching_numpy` (same result) straight from the MjData arrays."""
        _, kind, tp, heights = self._fast
        if not self._fast_touching_ok(g_hat):         # tilted gravity on a heightfield: numpy explains
            return self._touching_numpy(data, g_hat, work)
        a = work.args or self._fixed_args(data, work)
        k = fastkernel.touching(*a[0], g_hat, self._max_height, kind, tp, heights, *a[1])
        if k < 0:
            return self._touching_numpy(data, g_hat, work)  # raises the non-finite state error
        return work.touch[:k]

    def _wrenches(self, work, touch, v_com, omega, acc, dt, g_hat, groups, count, max_depth):
        """RFT octant wrenches (k, 8, 6), counts (k,), max depths (k,) of the touching bodies (rows of
        the workspace pose buffers), and whether any is non-zero. ``acc`` (k, 6) or None."""
        k = touch.size
        media, guards = self._media, self.guards
        if self._fast is not None:
            arrays, kind, tp, heights = self._fast
            n = fastkernel.wrenches(
                touch, k, *arrays, work.body_pos, work.body_mat, work.body_com, v_com, omega,
                _NO_ROWS if acc is None else acc, dt if self.stabilize else 0.0, g_hat, self._max_height,
                kind, tp, heights, media.xi_n_at(self._g_mag), law.COEFFICIENTS, media.mu_surf,
                guards.no_tension, guards.no_forward_tangential, guards.no_positive_power, self._tol,
                work.scratch, groups, count, max_depth)
            return groups[:k], count[:k], max_depth[:k], n > 0
        sel = np.concatenate([np.arange(self._elem_slices[i], self._elem_slices[i + 1]) for i in touch])
        remap = np.empty(len(self.body_ids), dtype=np.int64)
        remap[touch] = np.arange(k)
        out = kernel.body_wrenches(
            self.local_centroids[sel], self.local_normals[sel], self.areas[sel], remap[self.elem_body[sel]],
            k, work.body_pos[:k], work.body_mat[:k].reshape(k, 3, 3), work.body_com[:k], v_com, omega,
            self.terrain, g_hat, self._gravity_vec, media, guards, None if acc is None else acc[:, :3],
            None if acc is None else acc[:, 3:], dt if self.stabilize else 0.0, self.elem_octant[sel])
        return (*out, bool(np.any(out[0] != 0.0)))

    def _finish_numpy(self, diag, groups, count, max_depth, v_com, omega, limited, touch, sand_out) -> int:
        """Numpy reference of :func:`rft_mujoco.fastkernel.finish`: applied wrenches and diagnostics.
        Returns 1 when a wrench is non-zero, 0 when none, -1 when one is not finite (nothing written)."""
        _clear(diag)
        wrench = groups.sum(axis=1)
        diag.rft_force[touch] = wrench[:, :3]
        loaded = np.flatnonzero(np.any(wrench != 0.0, axis=1))
        if loaded.size and limited is not None:
            rft_norm = np.linalg.norm(wrench[loaded], axis=1)
            diag.scale[touch[loaded]] = np.linalg.norm(limited[loaded], axis=1) / rft_norm
            wrench = limited
        elif loaded.size and self.passive and not self.stabilize:
            power = np.einsum("ij,ij->i", wrench[loaded, :3], v_com[loaded]) + \
                np.einsum("ij,ij->i", wrench[loaded, 3:], omega[loaded])
            pos = power > 0.0
            wrench[loaded[pos]] = 0.0
            diag.scale[touch[loaded[pos]]] = 0.0
        diag.force[touch] = wrench[:, :3]
        diag.torque[touch] = wrench[:, 3:]
        diag.submerged[touch] = count
        diag.max_depth[touch] = max_depth
        if not np.all(np.isfinite(wrench)):
            return -1
        sand_out[self.body_ids[touch]] += wrench
        return int(np.any(wrench != 0.0))

    def _free_motion(self, data, bids, user_xfrc, dt):
        """Body Jacobians at the COM (k, 6, nv), predicted qvel (nv,) and free qacc (nv,) without sand.

        The free acceleration uses the smooth forces (passive, bias, actuators, applied, user xfrc) and
        ignores constraint forces (rigid contacts, limits).
        """
        m = self.model
        jac = np.empty((bids.size, 6, m.nv))
        for i, b in enumerate(bids):
            mujoco.mj_jacBodyCom(m, data, self._jacp, self._jacr, int(b))
            jac[i, :3] = self._jacp
            jac[i, 3:] = self._jacr
        mujoco.mj_fwdActuation(m, data)
        qfrc = data.qfrc_passive - data.qfrc_bias + data.qfrc_actuator + data.qfrc_applied
        rows = np.flatnonzero(np.any(user_xfrc[1:] != 0.0, axis=1)) + 1
        for b in rows:
            mujoco.mj_applyFT(m, data, user_xfrc[b, :3].copy(), user_xfrc[b, 3:].copy(),
                              data.xipos[b].copy(), int(b), qfrc)
        qacc = np.empty(m.nv)
        mujoco.mj_solveM(m, data, qacc.reshape(1, -1), qfrc.reshape(1, -1))
        if not np.all(np.isfinite(qacc)):
            names = [m.body(int(b)).name for b in bids]
            raise FloatingPointError(
                f"non-finite acceleration without sand while computing sand forces on bodies {names}: "
                "data.ctrl, data.qfrc_applied or data.xfrc_applied holds NaN/inf (or the model's "
                "actuators produce it); fix the input before stepping")
        return jac, data.qvel + dt * qacc, qacc

    def _limit(self, data, jac, groups, qvel_pred, dt, radius, column):
        """Stabilized wrenches (k, 6) of the candidate bodies from their RFT octant wrenches (k, 8, 6).

        A body is in the low-speed regime when its predicted speed (without sand) is below the speed
        change the full RFT impulse of one step would cause. Its octant wrenches get factors in [0, 1]
        that minimize the kinetic energy after the step (:func:`rft_mujoco.kernel.limit_impulses`): the
        sand stops it at most, never reverses or accelerates it. A body in flow gets the published force
        (every factor 1), unless that would add kinetic energy to the step; then every body is limited
        (passivity always holds). When the limiter binds on a low-speed body, up to
        ``kernel.REST_COLUMNS - 1`` more columns are added: the octant wrenches of the RFT resistance to
        the motion the body would still have after the step, sharing each octant's capacity with the
        first (convex combination). The sand can then supply any wrench
        of the convex hull of its resistances to several motions, which is what holds a tilted body at
        rest (one motion direction alone often cannot cancel both the weight and the sideways push).

        Args:
            jac: (k, 6, nv) body Jacobians at the COM; groups: (k, 8, 6) RFT octant wrenches;
            qvel_pred: (nv,) velocity after the step without sand; dt: step in s;
            radius: (k,) m, bounding radii (angular speeds count as ``radius * |omega|``);
            column: ``(v_lin (k, 3), v_ang (k, 3)) -> (k, 8, 6)`` RFT octant wrenches for body twists.
        """
        m = self.model
        n_groups = kernel.GROUPS_PER_BODY
        k = jac.shape[0]

        def minv(q):
            out = np.empty_like(q)
            mujoco.mj_solveM(m, data, out, np.ascontiguousarray(q))
            return out

        def speed(twist):
            return np.linalg.norm(twist[:, :3], axis=1) + radius * np.linalg.norm(twist[:, 3:], axis=1)

        flat = groups.reshape(-1, 6)
        group = np.flatnonzero(np.any(flat != 0.0, axis=1))       # (body, octant) of each column entry
        wrench = flat[group]
        q = np.einsum("kin,ki->kn", jac[group // n_groups], wrench)   # generalized forces J^T W
        minv_q = minv(q)
        G, h = dt * dt * (q @ minv_q.T), dt * (q @ qvel_pred)
        # Low-speed regime: the full RFT impulse of one step changes the body's speed by more than its
        # predicted speed. Those bodies get the energy-minimizing factors; bodies in flow keep the
        # published force (factor 1) unless it would add kinetic energy to the step, then all are limited.
        low = speed(jac @ qvel_pred) < speed(jac @ (dt * minv_q.sum(axis=0)))
        free = low[group // n_groups]
        lam = kernel.limit_impulses(G, h, group, free=free, ensure_passive=False) if free.any() else \
            np.ones(group.size)
        if 0.5 * lam @ G @ lam + h @ lam > 0.0:
            free[:] = True
            lam = kernel.limit_impulses(G, h, group)
        for _ in range(kernel.REST_COLUMNS - 1):
            refine = np.zeros(k, dtype=bool)
            refine[group[lam < 1.0 - 1e-12] // n_groups] = True
            refine &= low
            twist = jac @ (qvel_pred + dt * (minv_q.T @ lam))          # after the step, (k, 6)
            refine &= speed(twist) > kernel.REST_SPEED
            if not refine.any():
                break
            twist[~refine] = 0.0
            extra = column(twist[:, :3], twist[:, 3:]).reshape(-1, 6)
            new = np.flatnonzero(np.any(extra != 0.0, axis=1))
            if new.size == 0:
                break
            q_new = np.einsum("kin,ki->kn", jac[new // n_groups], extra[new])
            group = np.concatenate([group, new])
            wrench = np.concatenate([wrench, extra[new]])
            q = np.concatenate([q, q_new])
            minv_q = np.concatenate([minv_q, minv(q_new)])
            free = np.concatenate([free, np.ones(new.size, dtype=bool)])
            lam = kernel.limit_impulses(dt * dt * (q @ minv_q.T), dt * (q @ qvel_pred), group,
                                        np.concatenate([lam, np.zeros(new.size)]), free)
        out = np.zeros((k, 6))
        np.add.at(out, group // n_groups, wrench * lam[:, None])
        return out


def attach(model, media: Media | str, bodies: Sequence[str | int] | None = None,
           surface_height: float | Terrain = 0.0, resolution: str | float = "default", *,
           guards: Guards = PUBLISHED, stabilize: bool = True, passive: bool = True,
           monitor: bool | ValidityMonitor = True, backend: str = "auto", warm_start: bool = False,
           rk4_stages: str = "all") -> SandHandle:
    """Attach 3D-RFT sand to ``model``: from now on ``mujoco.mj_step(model, data)`` includes it.

    Args:
        model: the MjModel.
        media: a :class:`Media` or a preset name (see ``rft_mujoco.PRESETS``).
        bodies: body names (or ids) whose geoms touch the sand; None means every body but the world.
        surface_height: a flat free surface height in m, or a terrain (:class:`FlatSurface`,
            :class:`HeightfieldSurface`, :class:`SandRegion`).
        resolution: element size: a preset name (``rft_mujoco.surface.RESOLUTIONS``) or metres.
        guards: clean-ups of the fit's artefacts (default none: the published law).
        stabilize: low-speed regularization and impulse limiting, which gives real rest on sand and
            guarantees the sand never adds kinetic energy in a step (default True); the published force
            is recovered to ``(|a_free| dt / v)^3`` at speeds ``v`` above ``|F_rft| dt / m``
            (:mod:`rft_mujoco.stability`). False applies the published force at every element's current
            velocity (the naive coupling: bodies chatter instead of resting).
        passive: with ``stabilize=False``, zero a body's wrench whenever it would do positive work.
        monitor: warn (:class:`rft_mujoco.RFTValidityWarning`, once per reason) when a loaded body leaves
            the quasi-static regime or the validated depth (:mod:`rft_mujoco.monitor`); a
            :class:`ValidityMonitor` to set the check interval; False switches it off.
        backend: the per-evaluation kernel: "numba" (compiled, :mod:`rft_mujoco.fastkernel`; compiled
            once per machine and cached), "numpy" (:mod:`rft_mujoco.kernel`, the readable reference), or
            "auto" (default: numba when it imports and supports the terrain, else numpy). Both give the
            same forces to round-off.
        warm_start: with stabilize=True and the numba backend, start the impulse limiter's solver from
            its factors of the previous step and stop it after fewer sweeps: 2x faster on a standing
            quadruped and as accurate on average, but resting bodies keep 0.08-0.3 mm/s of jitter in a
            few of the stability cases, against 1e-6 m/s by default (:mod:`rft_mujoco.fastlimit`). Like
            MuJoCo's own solver warm start, the result then depends on the previous step as well as on the
            state; it is cleared whenever time does not advance by at most one step (resets), so rollouts
            from a reset are reproducible. False (default): every step is a function of the state alone.
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
    handle.warm_start = bool(warm_start)
    handle.rk4_stages = rk4_stages
    DISPATCHER.register(handle)
    handle.attached = True
    return handle


def detach_all() -> None:
    """Detach every sand handle in the process (and restore the user's own control callback)."""
    for h in DISPATCHER.handles:
        h.detach()
