"""What a sand handle keeps per MjData: the :class:`Diagnostics` of its last evaluation and the
:class:`_Workspace` of arrays the evaluations (compiled and numpy) read and write."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from rft_mujoco import tol
from rft_mujoco.compiled import schema as sc
from rft_mujoco.coupling import reference
from rft_mujoco.physics.deform import DeformableSurface


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
        occluded_area: (B,) m^2, submerged surface inside another body's geom (culled this evaluation).
    """

    force: np.ndarray
    torque: np.ndarray
    submerged: np.ndarray
    max_depth: np.ndarray
    scale: np.ndarray
    rft_force: np.ndarray
    resting: np.ndarray
    occluded_area: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> "Diagnostics":
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, dtype=np.int64), np.zeros(n), np.ones(n),
                   np.zeros((n, 3)), np.zeros(n, dtype=bool), np.zeros(n))

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
        self.occluded_area[:] = 0.0


class SolveCounters(NamedTuple):
    """How the sand solve went on one MjData since its workspace was made (at its first evaluation, or copied
    with it): :meth:`rft_mujoco.SandHandle.counters`. The same on every backend but ``reused_wrenches``.

    Attributes:
        kept_evaluations: evaluations at RK4 stages 2-4 that kept the first stage's mobility and rest factor.
        locked_dofs: dofs held by their dry friction (``frictionloss``) in the last evaluation's rest solve.
        locked_evaluations: evaluations whose rest solve held any dof by its dry friction.
        newton_iterations: Newton iterations of the last evaluation's implicit solve (``solve="implicit"``).
        reused_wrenches: bodies' RFT wrenches taken again from an earlier evaluation (``attach(reuse_tol=)``;
            the compiled backend's: the numpy reference evaluates every body every time).
    """

    kept_evaluations: int
    locked_dofs: int
    locked_evaluations: int
    newton_iterations: int
    reused_wrenches: int = 0


class _Workspace:
    """Per-MjData state of one handle (datas may be stepped in different threads): the arrays of
    :data:`rft_mujoco.compiled.evaluate.WORK_FIELDS` (the diagnostics are views of them), their tuple for the
    compiled calls, and the tuple of the MjData's arrays. With a
    :class:`~rft_mujoco.physics.deform.DeformableSurface` terrain, ``surface`` is this MjData's deformed surface
    (its arrays are ``arrays["surface_heights"]``, ``["surface_preload"]``, ``["surface_cycles"]`` and
    ``["surface_reach"]``, with ``["surface_clock"]`` (2,) the times of its last update and of the last evaluation
    with bodies touching, s, so that copies of the
    workspace copy it) and ``terrain`` is that surface; otherwise ``surface`` is None and ``terrain`` the
    handle's. ``hc`` is the handle constants the compiled evaluation of this MjData reads: the handle's, except
    with a deformable terrain, whose heights (``(2 ny, nx)``: this surface's heights over its preload, of which
    ``surface.heights`` and ``surface.preload`` are views) and ``params`` (``["surface_params"]``: the handle's
    settings with this surface's highest point) are this MjData's; ``press`` the compiled grid update's buffers
    (:func:`rft_mujoco.compiled.deform.buffers`; its state ``["surface_live"]``)."""

    __slots__ = ("arrays", "tuple", "md", "diag", "keep", "flowing", "surface", "terrain", "implicit", "hc", "press")

    def __init__(self, handle, data) -> None:
        from rft_mujoco.compiled import evaluate
        a = evaluate.build_workspace(len(handle.body_ids), handle.groups.ref.size, handle.model.nv,
                                     handle._cluster_width)
        self.arrays = a
        self.tuple = tuple(a[name] for name, _ in evaluate.WORK_FIELDS)
        self.md = evaluate.mjdata_arrays(data) if handle.evaluator.spec is not None else None
        self.diag = Diagnostics(a["force"], a["torque"], a["submerged"], a["max_depth"], a["scale"],
                                a["rft_force"], a["resting"], a["occluded_area"])
        self.keep = reference.StepKeep()
        self.flowing = None                 # the implicit solve's (touching groups, flowed) of the last evaluation
        self.surface = None
        self.terrain = handle.terrain
        self.hc = handle.evaluator.constants  # the compiled evaluation's handle constants (None: numpy)
        self.press = None                   # the compiled grid update's buffers (a deformable terrain)
        if isinstance(self.terrain, DeformableSurface):
            fresh = self.terrain.initial()
            if self.hc is not None:         # compiled: this MjData's heights and preload in the kernels' array
                from rft_mujoco.compiled import deform, terrain
                grid = terrain.deformable_heights(self.terrain)
                ny = self.terrain.shape[0]
                fresh = type(fresh)(self.terrain, grid[:ny], grid[ny:], fresh.cycles, fresh.reach)
                self.press = deform.buffers(self.terrain.shape, self.hc[evaluate.sc.H_CENTROIDS].shape[1])
                a["surface_live"], a["surface_stats"] = self.press["live"], self.press["stats"]
                a["surface_params"] = handle._params.copy()             # max_height: this surface's
                self.hc = tuple(grid if name == "heights" else a["surface_params"] if name == "params" else x
                                for (name, _), x in zip(evaluate.HANDLE_FIELDS, self.hc))
            a["surface_heights"], a["surface_preload"] = fresh.heights, fresh.preload
            a["surface_cycles"], a["surface_reach"] = fresh.cycles, fresh.reach
            a["surface_clock"] = np.full(2, -np.inf)
            self.surface = self.terrain = fresh
        self.implicit = None                # the compiled implicit solve's buffers (coupling.implicit.ImplicitWork)

    @property
    def state(self) -> np.ndarray:
        """(last time s, clean, touching, lagged, evaluations, RK4 stage, ...):
        :data:`rft_mujoco.compiled.evaluate.STATE`."""
        return self.arrays["state"]

    def counters(self) -> SolveCounters:
        """The solve's counters of this MjData (:class:`SolveCounters`)."""
        s = self.arrays["state"]
        return SolveCounters(int(s[sc.S_KEPT_EVALUATIONS]), int(s[sc.S_LOCKED_DOFS]), int(s[sc.S_LOCKED_EVALUATIONS]),
                             int(s[sc.S_NEWTON_ITERATIONS]), int(s[sc.S_REUSED_WRENCHES]))

    def record(self, outcome: reference.Outcome) -> None:
        """Count what one evaluation of the numpy reference did (the compiled kernels count in ``state``
        themselves, :data:`rft_mujoco.compiled.schema.STATE`)."""
        s = self.arrays["state"]
        s[sc.S_KEPT_EVALUATIONS] += 1.0 if outcome.kept else 0.0
        s[sc.S_LOCKED_DOFS] = outcome.locked_dofs
        s[sc.S_LOCKED_EVALUATIONS] += 1.0 if outcome.locked_dofs else 0.0
        s[sc.S_NEWTON_ITERATIONS] = outcome.newton_iterations

    def follow_time(self, t: float, dt: float) -> bool:
        """Record an evaluation at time ``t``; True when time advanced by at most one step since the last
        one (RK4 stages included): only then is MuJoCo's previous constraint solve this motion's."""
        s = self.arrays["state"]
        continuous = 0.0 <= t - s[sc.S_LAST_TIME] <= dt * (1.0 + tol.TIME_RTOL)
        s[sc.S_LAST_TIME] = t
        s[sc.S_LAGGED] = float(continuous)
        return continuous
