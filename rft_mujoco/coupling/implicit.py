"""The implicit solve (``attach(solve="implicit")``) on the compiled backend: the Python side of one
evaluation, between the broadphase and the kernels of :mod:`rft_mujoco.compiled.implicit_eval`.

The dispatcher's Python path (:meth:`rft_mujoco.coupling.dispatch.Dispatcher._evaluate`: a handle with an
observer, or where the native route cannot be built) runs the compiled phases:
:func:`rft_mujoco.compiled.evaluate.broadphase`, ``mj_fwdActuation``, then :func:`evaluate_compiled`; the
native route runs the same kernels from C (:mod:`rft_mujoco.compiled.implicit_route`, bit for bit the same).
The numpy reference of the same evaluation is :func:`rft_mujoco.coupling.reference.evaluate_implicit`.
"""

from __future__ import annotations

import mujoco
import numpy as np

_IMPLICIT = (int(mujoco.mjtIntegrator.mjINT_IMPLICIT), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))


class ImplicitWork:
    """Per-(handle, MjData) buffers of the compiled implicit solve: the arrays of
    :data:`rft_mujoco.compiled.implicit_eval.IMPLICIT_FIELDS` and their tuple, the (nv,) implicit damping, the
    solve's settings (:func:`rft_mujoco.compiled.implicit.settings`) and views of the model arrays the damping
    is computed from (read at every evaluation: edits of damping or servo gains are followed)."""

    __slots__ = ("arrays", "tuple", "damping", "settings", "model_arrays")

    def __init__(self, handle, arrays=None) -> None:
        from rft_mujoco.compiled import implicit, implicit_eval, schema
        m = handle.model
        if arrays is None:
            width = handle.evaluator.constants[schema.H_CENTROIDS].shape[1]
            arrays = implicit_eval.build_implicit(width, len(handle.body_ids), handle.groups.ref.size, m.nv)
        self.arrays = arrays
        self.tuple = tuple(arrays[name] for name, _ in implicit_eval.IMPLICIT_FIELDS)
        self.damping = np.zeros(m.nv)
        self.settings = implicit.settings()
        self.model_arrays = (m.dof_damping, np.ascontiguousarray(m.jnt_dofadr, dtype=np.int64), m.actuator_trntype,
                             m.actuator_trnid, m.actuator_biastype, m.actuator_biasprm, m.actuator_gear)

    def copy(self, handle) -> "ImplicitWork":
        """A copy of the per-MjData state (for :meth:`rft_mujoco.coupling.handle.SandHandle._copy_workspace`)."""
        return ImplicitWork(handle, {name: a.copy() for name, a in self.arrays.items()})


def implicit_work(handle, work) -> ImplicitWork:
    """The compiled implicit solve's buffers of ``handle`` on the MjData of ``work``, created at the first use."""
    if work.implicit is None:
        work.implicit = ImplicitWork(handle)
    return work.implicit


def table_part(handle, work, data) -> list:
    """The handle's part of the native route's table (:func:`rft_mujoco.compiled.implicit_route.table_part`)."""
    from rft_mujoco.compiled import implicit_route
    return implicit_route.table_part(handle, implicit_work(handle, work), data)


def cfunc_address() -> int:
    """The implicit evaluation's C function (:func:`rft_mujoco.compiled.implicit_route.cfunc_address`)."""
    from rft_mujoco.compiled import implicit_route
    return implicit_route.cfunc_address()


def evaluate_compiled(handle, data, work, user_xfrc: np.ndarray, dt: float, sand_out: np.ndarray) -> int:
    """The compiled implicit solve of the touching bodies the broadphase found (``work.state[2]``), after
    ``mj_fwdActuation``: wrenches added into ``sand_out`` (nbody, 6), the diagnostics written. Returns the
    status of :func:`rft_mujoco.compiled.implicit_eval.evaluate_implicit`."""
    from rft_mujoco.compiled import implicit_eval, system
    m = handle.model
    iw = implicit_work(handle, work)
    d_, adr, trn, trnid, bias, biasprm, gear = iw.model_arrays
    system.velocity_damping(int(m.opt.integrator) in _IMPLICIT, d_, adr, trn, trnid, bias, biasprm, gear,
                            iw.damping)
    system = (implicit_eval.efc_arrays(data), bool(mujoco.mj_isSparse(m)), data.M, iw.damping,
              handle.constraints == "linearized")                                         # implicit_eval.SYSTEM
    return implicit_eval.evaluate_implicit(work.md, work.hc, work.tuple, iw.tuple, user_xfrc, dt, sand_out, system,
                                           iw.settings)
