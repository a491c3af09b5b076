"""The evaluation behind a sand handle, one evaluator per backend (issue 30's seam).

A :class:`~rft_mujoco.coupling.handle.SandHandle` holds one evaluator, chosen when its terrain is set:
:class:`NumpyEvaluator` (``backend="numpy"``: the reference, :mod:`rft_mujoco.coupling.reference`, the oracle
the compiled path is tested against) or :class:`CompiledEvaluator` (``backend="numba"``: the kernels of
:mod:`rft_mujoco.compiled`, from the terrain's kernel spec and the handle's constants; the dispatcher's native
route runs the same kernels from the same constants without Python). Both evaluate the bodies of one MjData
into the sum of the sand wrenches and keep their per-MjData state in the handle's workspace
(:class:`~rft_mujoco.coupling.workspace._Workspace`): the counters of :class:`~rft_mujoco.coupling.workspace.
SolveCounters` are written by the compiled kernels themselves and, for the reference, by :class:`NumpyEvaluator`
from what the reference returns (:class:`~rft_mujoco.coupling.reference.Outcome`).

The handle calls :meth:`evaluate` after it has made the workspace, recorded the RK4 stage in it and checked the
floor; the handle's observers see the wrenches of either evaluator (:meth:`SandHandle.observe`).
"""

from __future__ import annotations

import mujoco
import numpy as np

from rft_mujoco.compiled import schema as sc
from rft_mujoco.coupling import checks, deformable, implicit, reference
from rft_mujoco.physics.terrain_spec import TerrainSpec


class NumpyEvaluator:
    """The numpy reference's evaluation (``backend="numpy"``).

    Attributes:
        backend: ``"numpy"``.
        spec, constants: None (no compiled terrain, no handle constants); :class:`CompiledEvaluator` has them.
    """

    backend = "numpy"
    spec = None
    constants = None

    def evaluate(self, handle, data, work, user_xfrc: np.ndarray, sand_out: np.ndarray) -> bool:
        """Add the wrenches (N, N m, world frame, about each body's COM) of ``handle``'s bodies on ``data`` into
        ``sand_out`` (nbody, 6); True when any is non-zero. ``work``: the handle's workspace of ``data``."""
        dt = handle.model.opt.timestep
        stage = int(work.state[sc.S_RK4_STAGE])
        handle._evaluations += 1
        g_hat = handle._gravity()
        lagged = work.follow_time(data.time, dt)
        if stage < 2:
            work.keep.clear()
        touch = reference.touching(handle, data, g_hat, work)
        if touch.size == 0:
            if work.state[sc.S_CLEAN] == 0.0:
                work.diag.clear()
                work.state[sc.S_CLEAN] = 1.0
            return False
        work.state[sc.S_CLEAN] = 0.0
        if handle.stabilize and handle.solve == "implicit":
            outcome = reference.evaluate_implicit(handle, data, user_xfrc, work, touch, dt, g_hat, lagged, sand_out)
        elif handle.stabilize:
            outcome = reference.evaluate_rest(handle, data, user_xfrc, work, touch, dt, g_hat, lagged, stage,
                                              sand_out)
        else:
            outcome = reference.evaluate_naive(handle, data, work, touch, g_hat, sand_out)
        work.record(outcome)
        if outcome.status < 0:
            checks.raise_not_finite(handle.body_names, work.diag, touch)
        if work.surface is not None and stage < 2:
            deformable.press_touching(handle, data, work, touch)
        handle._check_validity(data, work, touch, handle._evaluations)
        return bool(outcome.status)


class CompiledEvaluator:
    """The compiled evaluation (``backend="numba"``).

    Attributes:
        backend: ``"numba"``.
        spec: the terrain's kernel spec, a :class:`~rft_mujoco.physics.terrain_spec.TerrainSpec` ``(kind, params,
            heights)`` (:func:`rft_mujoco.physics.terrain_spec.terrain_spec`).
        constants: the handle constants ``hc`` (:data:`rft_mujoco.compiled.schema.HANDLE_FIELDS`), shared by every
            MjData but one on a deformable terrain (each has its own heights: the workspace's ``hc``).
    """

    backend = "numba"

    def __init__(self, spec: TerrainSpec, constants: tuple) -> None:
        self.spec = spec
        self.constants = constants

    def evaluate(self, handle, data, work, user_xfrc: np.ndarray, sand_out: np.ndarray) -> bool:
        """As :meth:`NumpyEvaluator.evaluate`, by the compiled kernels."""
        from rft_mujoco.compiled import evaluate
        dt = handle.model.opt.timestep
        handle._gravity()                                # raises on a zero gravity set after attach
        k = evaluate.broadphase(work.md, work.hc, work.tuple, data.time, dt)
        if k == evaluate.NOT_FINITE_STATE:
            reference.touching(handle, data, handle._g_hat, work)     # raises the non-finite state error
        if k <= 0:
            return False
        if handle.stabilize:
            mujoco.mj_fwdActuation(handle.model, data)
        status = implicit.evaluate_compiled(handle, data, work, user_xfrc, dt, sand_out) \
            if handle.stabilize and handle.solve == "implicit" else \
            evaluate.evaluate(work.md, work.hc, work.tuple, user_xfrc, dt, sand_out, evaluate.friction_arrays(data))
        touch = work.arrays["touch"][:k]
        if status == evaluate.BAD_ACCELERATION:                      # raises
            reference.free_twists(handle, data, user_xfrc, handle.body_ids[handle.groups.ref], dt, False)
        if status < 0:
            checks.raise_not_finite(handle.body_names, work.diag, touch)
        if work.press is not None and work.state[sc.S_RK4_STAGE] < 2:
            deformable.press_compiled(handle, data, work, k)
        handle._check_validity(data, work, touch, int(work.state[sc.S_EVALUATIONS]))
        return bool(status)
