"""MuJoCo coupling: attach 3D-RFT sand to bodies of a model; plain ``mujoco.mj_step`` then includes it.

Each physics evaluation (every integrator stage: once per step for Euler/implicit/implicitfast, four
times for RK4) the dispatcher (:mod:`rft_mujoco.coupling.dispatch`) evaluates every handle of the model:

1. broadphase: bodies whose bounding sphere is above the highest point of the sand are skipped, and the
   bodies with a submerged element found; nothing else runs when none is;
2. element states from ``xpos``/``xmat`` and ``cvel`` (whose linear part refers to ``subtree_com`` of the
   root, converted to each body's COM); elements inside a geom of another weld group (a calf inside its
   thigh at the knee) carry nothing (run-time culling; culling inside a body and its weld group is done
   once, at attach: :mod:`rft_mujoco.coupling.setup`);
3. with ``stabilize=True`` (default), the sand solve of ``attach(solve=...)`` per touching *group* (the
   attached bodies of one weld group): "explicit" (:mod:`rft_mujoco.physics.rest`: rest or flow, with the
   constraint forces of MuJoCo's previous solve) or "implicit" (:mod:`rft_mujoco.physics.implicit`: the law
   at the motion the step ends with, this step's constraints linearized); docs/rest.md. With
   ``stabilize=False``, the published force at each element's velocity (the naive coupling);
4. the wrenches are added to ``data.xfrc_applied`` on top of the user's own wrench (the dispatcher's book);
5. every ``monitor.every`` evaluations, the loaded bodies are checked against the validity range of 3D-RFT
   (:mod:`rft_mujoco.coupling.monitor`; ``attach(monitor=False)`` switches it off).

Steps 1-4 run compiled (:mod:`rft_mujoco.compiled`, the default) or in the numpy reference
(:mod:`rft_mujoco.coupling.reference`, ``backend="numpy"``); the tests compare the two.
"""

from __future__ import annotations

import copy
import numbers
import warnings
import weakref
from collections.abc import Sequence

import mujoco
import numpy as np

from rft_mujoco import compiled, tol
from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.element_pass import REUSE_VALID
from rft_mujoco.coupling import checks, deformable, layout, setup
from rft_mujoco.coupling.book import RK4_STAGES
from rft_mujoco.coupling.dispatch import DISPATCHER
from rft_mujoco.coupling.evaluators import CompiledEvaluator, NumpyEvaluator
from rft_mujoco.coupling.monitor import ValidityMonitor
from rft_mujoco.coupling.workspace import Diagnostics, SolveCounters, _Workspace
from rft_mujoco.geometry import surface
from rft_mujoco.physics import law, rest
from rft_mujoco.physics.law import PUBLISHED, Guards, gravity_direction
from rft_mujoco.physics.media import Media, f_hat, get_media
from rft_mujoco.physics.deform import DeformedSurface
from rft_mujoco.physics.terrain import Terrain
from rft_mujoco.physics.terrain_spec import terrain_spec

BACKENDS = ("auto", "numba", "numpy")
"""Backends of :func:`attach`: numba-compiled (:mod:`rft_mujoco.compiled`) or numpy (the readable reference,
:mod:`rft_mujoco.coupling.reference`); "auto" is numba when it imports and supports the terrain, numpy
otherwise."""
SOLVES = ("explicit", "implicit")
"""Values of ``attach(solve=...)``: the explicit rest/flow treatment (:func:`rft_mujoco.physics.rest.rest_wrenches`)
or the implicit solve (:func:`rft_mujoco.physics.implicit.implicit_wrenches`, this step's constraints linearized:
:func:`rft_mujoco.coupling.reference.constrained_free_motion`; compiled: :mod:`rft_mujoco.coupling.implicit`)."""
CONSTRAINTS = ("linearized", "lagged")
"""Values of ``handle.constraints``, the implicit solve's constraint forces: this step's rows linearized in their
zones (the default), or MuJoCo's previous constraint forces (the first of the implicit solve's two changes
alone, a measurement: docs/rest.md, "The implicit solve")."""
REUSE_TOL_MAX = 0.1
"""The largest ``attach(reuse_tol=...)``: beyond it a reused wrench could be off by more than a few percent."""
REUSE_TOL_DEFAULT = 1e-3
"""``attach(reuse_tol=...)``'s default: a body's wrench is reused while its motion's direction and its pose change by
less than about 0.1% (docs/performance.md, "Reusing a body's wrench": the answers measured the same as with 0)."""


class SandHandle:
    """Sand attached to some bodies of one MjModel. Create with :func:`attach`; remove with :meth:`detach`.

    Attributes:
        model: the MjModel. The handle does not keep it alive: when the model is garbage collected (the user's
            last reference to it and to its MjDatas gone), its sand is detached and ``model`` raises
            ReferenceError (docs/architecture.md, "Lifetime").
        media: the granular medium.
        terrain: the free surface.
        body_ids: (B,) int, bodies that feel the sand.
        body_names: their names.
        n_elements: total surface elements (candidates) over those bodies, after culling at attach.
        culled_area: (B,) m^2 of each body's surface culled at attach (inside its other geoms, or inside a
            geom welded to it); the diagnostics' ``occluded_area`` reports run-time culling.
        evaluations: sand evaluations so far (all MjData together).
        stabilize: the rest treatment is on (see :func:`attach`).
        rk4_stages: with integrator="RK4", "all", "midpoint" or "first" (see :func:`attach`).
        cull: only the exposed surface feels sand (see :func:`attach`).
        layout: the elements, weld groups, bounding spheres and run-time occluders built at attach
            (:class:`rft_mujoco.coupling.layout.Layout`; the warp path builds the same).
        solve: ``"explicit"`` or ``"implicit"`` (see :func:`attach`); constraints: the implicit solve's
            constraint forces (:data:`CONSTRAINTS`).
    """

    def __init__(self, model, media: Media, body_ids: Sequence[int], terrain: Terrain, size: float,
                 guards: Guards, stabilize: bool, passive: bool, monitor: bool | ValidityMonitor = True,
                 backend: str = "auto", cull: bool = True):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self._ready = False
        self._params = np.zeros(len(sc.PARAMS))
        self._model = weakref.ref(model)     # the dispatcher unregisters the handle when the model is collected
        self.element_size = size
        self.body_ids = np.asarray(body_ids, dtype=np.int64)
        self.body_names = [model.body(int(b)).name for b in self.body_ids]
        self.cull = bool(cull)
        self.layout = layout.build(model, self.body_ids, size, self.cull)
        lay = self.layout
        self.local_centroids, self.local_normals, self.areas, self.elem_body = (lay.centroids, lay.normals,
                                                                                lay.areas, lay.elem_body)
        self.culled_area, self.n_elements, self.groups = lay.culled_area, lay.n_elements, lay.groups
        # the geoms whose sizes the elements and occluders were built from (model edits: _check_model)
        self._geoms = np.union1d(np.flatnonzero(np.isin(model.geom_bodyid, self.body_ids)),
                                 lay.occluders.geom).astype(np.int64)
        self._geom_size0 = model.geom_size[self._geoms].copy()
        self._timestep_checked = float(model.opt.timestep)
        self._work: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
        self.attached = False
        self._evaluations = 0
        self.monitor = (monitor if isinstance(monitor, ValidityMonitor) else
                        ValidityMonitor() if monitor else None)
        self._replaced: list[tuple[int, int, int]] = []
        self._floor_checked = False
        self._opt_gravity = model.opt.gravity            # a live view: gravity changes are seen
        self._gravity_seen = None
        self._gravity_of_wrenches = tuple(self._opt_gravity)   # gravity of the wrenches remembered for reuse
        self.rk4_stages = "all"
        self.reuse_tol = REUSE_TOL_DEFAULT
        self.solve = "explicit"
        self.constraints = "linearized"                   # CONSTRAINTS
        self._observers: list = []
        self._backend_request = backend
        self._packed = None
        self._evaluator = NumpyEvaluator()               # set with the terrain (_select_backend)
        self._layout_ok = None
        self.media = media
        self.guards = guards
        self.stabilize = bool(stabilize)
        self.passive = bool(passive)
        self.terrain = terrain                           # selects the backend
        self._ready = True
        self._refresh()

    # --- settings that the compiled code reads (hc.params): every setter refreshes them -------------------
    def __setattr__(self, name, value) -> None:
        for key, allowed in (("constraints", CONSTRAINTS), ("rk4_stages", RK4_STAGES)):
            if name == key and value not in allowed:
                raise ValueError(f"{key} must be one of {tuple(allowed)}, got {value!r}")
        if name == "reuse_tol":
            value = checked_reuse_tol(value)
        object.__setattr__(self, name, value)
        if name in ("solve", "constraints") and getattr(self, "_ready", False):
            DISPATCHER.invalidate()                      # the native route is built with both
        if name in ("_media", "guards", "stabilize", "passive", "monitor", "_terrain", "rk4_stages", "reuse_tol") \
                and getattr(self, "_ready", False):
            self._refresh()
            if name in ("_media", "guards", "stabilize", "passive"):   # the law's answer changes
                self._forget_wrenches()

    def _refresh(self) -> None:
        """Rewrite ``hc.params`` (:data:`rft_mujoco.compiled.evaluate.PARAMS`) from the settings."""
        spec = self._evaluator.spec
        if spec is None:
            return
        from rft_mujoco.compiled import evaluate
        media = self._media
        every = self.monitor.every if self.monitor is not None else 0
        evaluate.params_array(self._max_height, media.rho_c * f_hat(media.mu_int), media.mu_surf, self.guards,
                              spec.kind, self.stabilize, self.passive, self.layout.occluders.margin, every,
                              RK4_STAGES[self.rk4_stages], self.reuse_tol, out=self._params)   # read live by the route
        for work in self._work.values():
            if work.press is not None:                   # a deformable surface's own copy, its own highest point
                np.copyto(work.hc[sc.H_PARAMS], self._params)
                work.hc[sc.H_PARAMS][sc.P_MAX_HEIGHT] = work.surface.max_height

    # --- public -------------------------------------------------------------------------------------
    @property
    def evaluations(self) -> int:
        """Sand evaluations so far (all MjData together)."""
        return self._evaluations + sum(int(w.state[sc.S_EVALUATIONS]) for w in self._work.values())

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

    @property
    def model(self):
        """The MjModel the sand is attached to (ReferenceError once it was garbage collected)."""
        model = self._model()
        if model is None:
            raise ReferenceError("this sand handle's MjModel was garbage collected, which detached its sand: a handle "
                                 "does not keep its model alive. Keep a reference to the model (or to an MjData of "
                                 "it) for as long as you use the handle")
        return model

    def detach(self) -> None:
        """Remove the sand: later steps are the plain model; sand wrenches are taken out of xfrc_applied."""
        if not self.attached:
            return
        model = self._model()
        DISPATCHER.unregister(self)
        if model is not None:
            for gid, contype, conaffinity in self._replaced:
                model.geom_contype[gid] = contype
                model.geom_conaffinity[gid] = conaffinity
            for data in DISPATCHER.datas_of(model):
                DISPATCHER.remove_sand(model, data, self.body_ids)
        self._replaced.clear()
        self.attached = False

    def _collected(self) -> None:
        """The model was garbage collected (its datas with it): nothing of it to restore, only unregister (the
        dispatcher calls this from the model's finalizer) and let go of the arrays that view the model's memory
        (they would keep that memory, though not the MjModel object, alive in a handle the user kept)."""
        if self.attached:
            DISPATCHER.unregister(self)
            self._replaced.clear()
            self._work.clear()
            self._evaluator.constants = None           # (the compiled evaluator's views of the model's arrays)
            self._opt_gravity = None
            self.attached = False

    def replace_rigid(self, geoms: str | int | Sequence[str | int]) -> None:
        """Switch off collisions of rigid geoms the sand replaces (e.g. the floor plane) until detach; warns
        (:func:`rft_mujoco.coupling.checks.check_replaced_floor`) when a replaced floor is not at the sand's height.

        ``geoms``: a geom name or id, or a sequence of them. Copies and saves of the model (``copy``,
        ``deepcopy``, pickle, ``mj_saveModel``) keep the geoms' own collision flags (docs/architecture.md,
        "State and copies")."""
        if isinstance(geoms, (str, int, np.integer)):
            geoms = [geoms]
        new = []
        for g in geoms:
            if not isinstance(g, (str, int, np.integer)):
                raise TypeError(f"replace_rigid takes geom names (str) or ids (int), got {g!r}")
            gid = g if isinstance(g, (int, np.integer)) else mujoco.mj_name2id(
                self.model, mujoco.mjtObj.mjOBJ_GEOM, g)
            if gid < 0 or gid >= self.model.ngeom:
                raise ValueError(f"no geom named {g!r} to replace by sand")
            self._replaced.append((int(gid), int(self.model.geom_contype[gid]),
                                   int(self.model.geom_conaffinity[gid])))
            self.model.geom_contype[gid] = 0
            self.model.geom_conaffinity[gid] = 0
            new.append(int(gid))
        checks.check_replaced_floor(self.model, new, self._terrain)

    def counters(self, data) -> SolveCounters:
        """How the sand solve went on ``data`` so far (:class:`~rft_mujoco.coupling.workspace.SolveCounters`:
        evaluations that kept the first RK4 stage's mobility, dofs held by dry friction now and evaluations
        that held any, Newton iterations of the last implicit solve); zeros before its first evaluation."""
        return self._workspace(data).counters()

    def diagnostics(self, data) -> Diagnostics:
        """Per-body force, torque, submerged element count, max depth and rest state of the latest
        evaluation of ``data`` (a live view, updated by later steps; ``.copy()`` keeps a snapshot)."""
        return self._workspace(data).diag

    def surface(self, data) -> DeformedSurface:
        """A copy of the deformed free surface of ``data`` now: ``.heights`` (ny, nx) m, ``.x`` (nx,) m, ``.y`` (ny,)
        m, ``.preload`` (ny, nx) m (:mod:`rft_mujoco.physics.deform`); ValueError unless the terrain is a
        :class:`~rft_mujoco.DeformableSurface`."""
        return deformable.snapshot(self, self._workspace(data))

    def surface_updated(self, data) -> float:
        """s, ``data.time`` at the last update of the deformed surface of ``data`` (-inf before the first; the
        grid is updated every ``DeformableSurface.update_interval``); ValueError as :meth:`surface`."""
        return deformable.updated_at(self, self._workspace(data))

    @property
    def terrain(self) -> Terrain:
        """The free surface; may be replaced between steps."""
        return self._terrain

    @terrain.setter
    def terrain(self, value: Terrain | float) -> None:
        value = checks.checked_terrain(value)
        self._max_height = float(value.max_height)
        self._select_backend(value)
        self._terrain = value

    @property
    def backend(self) -> str:
        """The backend in use: "numba" (:mod:`rft_mujoco.compiled`) or "numpy" (the reference)."""
        return self._evaluator.backend

    @property
    def evaluator(self) -> NumpyEvaluator | CompiledEvaluator:
        """The evaluation behind this handle (:mod:`rft_mujoco.coupling.evaluators`): the numpy reference or the
        compiled kernels, chosen with the terrain and ``backend``."""
        return self._evaluator

    def evaluation_path(self, data) -> str:
        """The path that evaluates this handle's sand on ``data`` now: "native" (the compiled route that MuJoCo's
        callbacks call directly: the fast path), "python" (the dispatcher's Python callback: the numpy backend,
        an observer, the first evaluations of a model) or "none" (not evaluated on
        ``data`` yet)."""
        if not isinstance(data, mujoco.MjData):
            raise TypeError(f"data must be a mujoco.MjData, got {type(data).__name__}")
        registry = DISPATCHER._registry
        if registry is not None and self.attached and registry.routed(self.model, data):
            return "native"
        return "none" if self._work.get(data) is None else "python"

    @property
    def _native_ok(self) -> bool:
        """Whether the native route may evaluate this handle: compiled, no observer."""
        return self._evaluator.backend == "numba" and not self._observers

    def _select_backend(self, terrain) -> None:
        from rft_mujoco.compiled.jit import AVAILABLE, IMPORT_ERROR
        request = self._backend_request
        spec = None
        if AVAILABLE and request != "numpy":
            spec = terrain_spec(terrain)
        if request == "numba" and not AVAILABLE:
            raise ValueError(f"backend='numba' needs numba, which failed to import ({IMPORT_ERROR}); "
                             "use backend='auto' or 'numpy'")
        if request == "numba" and spec is None:
            raise ValueError("backend='numba' supports FlatSurface, HeightfieldSurface, SandRegion and "
                             f"DeformableSurface terrains (those with a kernel_spec), got {type(terrain).__name__}; use "
                             "backend='auto' (numpy for this terrain) or 'numpy'")
        self._evaluator = NumpyEvaluator()
        if spec is not None and self._compiled_ok(request):
            self._evaluator = CompiledEvaluator(spec, self._handle_constants(spec))
        self._work.clear()                         # workspaces are per backend (the md tuple, buffer sizes)
        DISPATCHER.invalidate()

    def _compiled_ok(self, request) -> bool:
        try:
            compiled.ensure_compiled()
        except Exception as exc:  # a broken numba/LLVM install must not break the simulation
            if request == "numba":
                raise
            warnings.warn(f"rft_mujoco: the numba kernels failed to compile ({type(exc).__name__}: {exc}); "
                          "using the numpy reference (slower). Pass backend='numpy' to silence this.",
                          RuntimeWarning, stacklevel=4)
            return False
        if self._layout_ok is None:
            self._layout_ok = checks.mass_matrix_layout_ok(self.model, request)
        return self._layout_ok

    def _handle_constants(self, spec) -> tuple:
        from rft_mujoco.compiled import elements, evaluate
        from rft_mujoco.compiled.law import tolerances
        if self._packed is None:
            self._packed = elements.pack(self.local_centroids, self.local_normals, self.areas, self.elem_body,
                                         len(self.body_ids))
            starts = self._packed.cluster_start
            self._cluster_width = int(max(np.diff(starts).max(initial=0), 1))
        settings = np.array([rest.DEPENDENT_TOL, rest.WEIGHT_FLOOR, rest.CAPACITY_TOL, tol.TINY])
        return evaluate.handle_constants(self.model, self.layout, self._packed, spec, law.COEFFICIENTS, tolerances(),
                                         settings, self._params)

    _cluster_width = 128

    def __enter__(self) -> "SandHandle":
        return self

    def __exit__(self, *exc) -> None:
        self.detach()

    def summary(self) -> str:
        """What the sand sees, one row per attached body: the geoms used and whether they are collision or
        visual geoms, the exposed area (m^2) and the area culled at attach, the element count and the
        smallest geom dimension (m); ``print(handle)`` prints it (:func:`rft_mujoco.coupling.setup.describe`)."""
        rows = setup.describe(self.model, self.body_ids, self.elem_body, self.areas, self.culled_area)
        return f"{self!r}\n" + setup.summary_text(rows, self.element_size)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        return (f"SandHandle(media={self.media.name!r}, bodies={self.body_names}, "
                f"elements={self.n_elements}, element_size={self.element_size} m, backend={self.backend!r}, "
                f"attached={self.attached})")

    def observe(self, observer) -> None:
        """Call ``observer(data, wrenches, stage)`` after every sand evaluation of this handle, on every path.

        ``wrenches`` (B, 6): the sand wrench of each body of :attr:`body_ids` this evaluation (N, N m, world
        frame, about each body's COM; zero for bodies above the sand); ``stage``: the RK4 stage (1-4), 0 with
        another integrator. Studies record the sand's work with it. While a handle of a model has an observer,
        that model's evaluations take the Python path (the native route calls no Python): the forces are the
        same, the cost higher. Remove it with :meth:`unobserve`."""
        if not callable(observer):
            raise TypeError(f"observer must be callable as observer(data, wrenches, stage), got "
                            f"{type(observer).__name__}")
        self._observers.append(observer)
        DISPATCHER.invalidate()

    def unobserve(self, observer) -> None:
        """Stop calling ``observer`` (added with :meth:`observe`); ValueError if it is not observing."""
        try:
            self._observers.remove(observer)
        except ValueError:
            raise ValueError(f"{observer!r} is not an observer of this handle; observers: "
                             f"{self._observers!r}") from None
        DISPATCHER.invalidate()

    # --- per evaluation -----------------------------------------------------------------------------
    def _workspace(self, data) -> _Workspace:
        work = self._work.get(data) if isinstance(data, mujoco.MjData) else None
        if work is None:
            if not isinstance(data, mujoco.MjData) or data.xpos.shape[0] != self.model.nbody \
                    or data.qvel.shape[0] != self.model.nv:
                raise ValueError(f"data must be a mujoco.MjData of this handle's model (nbody {self.model.nbody}, "
                                 f"nv {self.model.nv}), got {type(data).__name__}"
                                 + (f" with nbody {data.xpos.shape[0]}, nv {data.qvel.shape[0]}"
                                    if isinstance(data, mujoco.MjData) else ""))
            work = self._work[data] = _Workspace(self, data)
        return work

    def _copy_workspace(self, src, dst) -> None:
        """``dst`` continues from ``src``'s per-MjData state (the dispatcher's :meth:`copy_state`)."""
        work = self._work.get(src)
        if work is None:
            return
        new = self._workspace(dst)
        for name, a in work.arrays.items():
            np.copyto(new.arrays[name], a)
        new.keep, new.flowing = copy.deepcopy(work.keep), work.flowing
        new.implicit = work.implicit and work.implicit.copy(self)

    def _evaluate(self, data, user_xfrc: np.ndarray, sand_out: np.ndarray, stage: int = 0) -> bool:
        """Add this handle's wrenches (nbody, 6) into ``sand_out``; True when any of them is non-zero (the
        dispatcher's Python path; its native route runs the compiled phases of every handle at once).
        ``stage``: the RK4 stage of this evaluation (1-4), 0 with another integrator."""
        if not self._observers:
            return self._evaluate_once(data, user_xfrc, sand_out, stage)
        before = sand_out[self.body_ids].copy()
        loaded = self._evaluate_once(data, user_xfrc, sand_out, stage)
        wrenches = sand_out[self.body_ids] - before
        for observer in tuple(self._observers):
            observer(data, wrenches, stage)
        return loaded

    def _check_floor(self) -> None:
        """At the first evaluation (after replace_rigid had its chance): warn about a rigid floor under the sand."""
        if not self._floor_checked:
            self._floor_checked = True
            checks.check_rigid_floor(self.model, self.body_ids, self._terrain)

    def _evaluate_once(self, data, user_xfrc: np.ndarray, sand_out: np.ndarray, stage: int = 0) -> bool:
        work = self._workspace(data)
        work.state[sc.S_RK4_STAGE] = stage
        self._check_floor()
        return self._evaluator.evaluate(self, data, work, user_xfrc, sand_out)

    def _check_validity(self, data, work, touch, count: int) -> None:
        """The validity monitor, every ``monitor.every`` evaluations of ``data``."""
        if self.monitor is not None and count % self.monitor.every == 0:
            k = touch.size
            a = work.arrays
            self.monitor.check(self, data, touch, a["v_com"][:k], a["omega"][:k], work.diag.max_depth[touch])

    def _check_model(self) -> None:
        """Raise ValueError on a model edit since attach that the sand cannot follow
        (:func:`rft_mujoco.coupling.checks.check_model_edits`); the dispatcher calls this at the first evaluation
        of each MjData and whenever the model's timestep, gravity or geom sizes change."""
        checks.check_model_edits(self)
        if tuple(self._opt_gravity) != self._gravity_of_wrenches:      # |g| scales the law (xi_n)
            self._gravity_of_wrenches = tuple(self._opt_gravity)
            self._forget_wrenches()

    def _forget_wrenches(self) -> None:
        """No wrench remembered for reuse (``attach(reuse_tol=)``) survives a change of the law (medium, guards, the
        rest treatment's settings, gravity): every MjData's next evaluation is a full one."""
        for reuse in (work.arrays.get("reuse") for work in self._work.values()):
            if reuse is not None:
                reuse[:, REUSE_VALID] = 0.0

    def _gravity(self) -> np.ndarray:
        """Unit gravity direction (3,), recomputed only when ``model.opt.gravity`` changed."""
        g = self._opt_gravity.tolist()
        if g != self._gravity_seen:
            g_hat, self._g_mag = gravity_direction(g)
            self._g_hat = np.ascontiguousarray(g_hat)
            self._gravity_seen = g
            if self._evaluator.spec is not None:
                from rft_mujoco.compiled.terrain import check_gravity
                check_gravity(self._terrain, self._evaluator.spec, self._g_hat)
        return self._g_hat


def checked_reuse_tol(value) -> float:
    """``attach(reuse_tol=...)`` as a float, or ValueError saying what is allowed."""
    if isinstance(value, bool) or not (isinstance(value, numbers.Real) and 0.0 <= value <= REUSE_TOL_MAX):
        raise ValueError(f"reuse_tol must be a number from 0 (off) to {REUSE_TOL_MAX}, got {value!r}; "
                         f"{REUSE_TOL_DEFAULT} (the default) reuses a body's wrench while its motion and pose hold")
    return float(value)


def attach(model, media: Media | str, bodies: Sequence[str | int] | None = None,
           surface_height: float | Terrain = 0.0, resolution: str | float = "default", *,
           guards: Guards = PUBLISHED, stabilize: bool = True, passive: bool = True,
           monitor: bool | ValidityMonitor = True, backend: str = "auto", rk4_stages: str = "all",
           cull: bool = True, solve: str = "explicit", reuse_tol: float = REUSE_TOL_DEFAULT) -> SandHandle:
    """Attach 3D-RFT sand to ``model``: from now on ``mujoco.mj_step(model, data)`` includes it.

    Args:
        model: the MjModel.
        media: a :class:`Media` or a preset name (see ``rft_mujoco.PRESETS``).
        bodies: body names (or ids) whose geoms touch the sand; None means every body but the world.
        surface_height: a flat free surface height in m, or a terrain (:class:`FlatSurface`,
            :class:`HeightfieldSurface`, :class:`SandRegion`, or :class:`DeformableSurface`: footprints,
            :meth:`SandHandle.surface`).
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
            the quasi-static regime or the validated depth, and (:class:`rft_mujoco.SandSetupWarning`, once)
            when the explicit solve often stops a body's flow within a step: a body light for it, which the
            implicit solve gets right (:mod:`rft_mujoco.coupling.monitor`); a
            :class:`ValidityMonitor` to set the check interval; False switches it off.
        backend: "numba" (compiled, cached after the first use on a machine), "numpy" (the readable
            reference), or "auto" (default: numba when it imports and supports the terrain, else numpy).
            Both give the same forces to round-off.
        rk4_stages: with ``integrator="RK4"``, "all" (default) evaluates the sand at every stage of a step;
            "midpoint" (the Gymnasium sand envs') at the first two (its start; t + dt/2 along the first
            stage's slope), the second's wrench held through stages 3-4; "first" at the first only. Later
            stages keep the first stage's mobility and rest factor while the same bodies touch (``StepKeep``
            in :mod:`rft_mujoco.coupling.reference`); errors and costs: docs/performance.md, "RK4 stages". A
            stage is skipped only where every handle of the model skips it (other integrators: one per step).
        cull: True (default): only the surface that sand can reach feels it; elements inside another geom
            of the same body or weld group are dropped at attach, and elements inside a geom of another
            body (a calf inside its thigh at the knee, a rock) carry nothing while they are inside it.
            False: every geom's whole surface feels sand (overlaps count twice; for comparisons).
        solve: with ``stabilize=True``, "explicit" (default: rest, or flow scaled not to reverse the motion,
            constraint forces of the previous solve) or "implicit" (the law at the twist the step ends with, per
            direction, this step's constraints linearized in the zones the step ends in; also on warp:
            ``rft_mujoco.warp.attach(solve="implicit")``; docs/rest.md "The implicit solve").
        reuse_tol: with the rest treatment's explicit solve on flat sand (compiled backend), a body's RFT
            wrench is taken again from its last full evaluation while, in the body's frame, the unit vector of
            its twist (COM velocity, 0.1 m x angular velocity) and the gravity direction have each moved by less
            than ``reuse_tol`` (sums of absolute component changes) and its origin by less than ``reuse_tol``
            x 10 mm in depth, and no other body's geom is near its elements in the sand (the law is rate
            independent and flat sand is the same everywhere: a standing robot, or a body sliding steadily,
            keeps its wrench). The default 1e-3 halves the standing quadruped's sand cost and leaves the answers
            measured the same (docs/performance.md, "Reusing a body's wrench"); 0: every evaluation evaluates
            every element; ``SandHandle.counters(data).reused_wrenches`` counts the reuses. At most 0.1. The
            numpy reference never reuses.
    Returns:
        a :class:`SandHandle`; call ``handle.detach()`` (or use it as a context manager) to remove it.
    """
    if not isinstance(model, mujoco.MjModel):
        raise TypeError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    if solve not in SOLVES:
        raise ValueError(f"solve must be one of {SOLVES}, got {solve!r}")
    if rk4_stages not in RK4_STAGES:
        raise ValueError(f"rk4_stages must be one of {tuple(RK4_STAGES)}, got {rk4_stages!r}")
    checked_reuse_tol(reuse_tol)
    if not isinstance(guards, Guards):
        raise TypeError(f"guards must be a rft_mujoco.Guards (default: rft_mujoco.PUBLISHED, no clean-ups), got "
                        f"{guards!r}; e.g. rft_mujoco.Guards(no_tension=True)")
    media = get_media(media)
    terrain = checks.checked_terrain(surface_height)
    size = surface.element_size(resolution)
    ids = setup.attachable_bodies(model, bodies)
    gravity_direction(model.opt.gravity)  # raises on zero gravity
    checks.check_not_attached(model, ids, DISPATCHER.handles, terrain=terrain)
    checks.check_timestep(model)
    if checks.check_actuation_flag(model):
        raise ValueError(checks.ACTUATION_DISABLED_MESSAGE)
    handle = SandHandle(model, media, ids, terrain, size, guards, stabilize, passive, monitor, backend, cull)
    checks.check_sand_surfaces(model, handle.body_ids, np.bincount(handle.elem_body, handle.areas,
                                                                   minlength=len(ids)) + handle.culled_area)
    checks.check_resolution(model, handle.body_ids, handle.element_size)
    handle.rk4_stages = rk4_stages
    handle.reuse_tol = reuse_tol
    handle.solve = solve
    DISPATCHER.register(handle)
    handle.attached = True
    return handle


def attached_handles() -> tuple[SandHandle, ...]:
    """The sand handles attached now in this process, in attach order: those not detached whose model is alive
    (a handle is detached when its model is garbage collected, kept by the user or not)."""
    return DISPATCHER.handles


def detach_all() -> None:
    """Detach every sand handle in the process (and restore the user's own control callback)."""
    for h in attached_handles():
        h.detach()
