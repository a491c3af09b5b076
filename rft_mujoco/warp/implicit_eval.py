"""One evaluation of the implicit solve on the batched sand (``rft_mujoco.warp.attach(solve="implicit")``): the
per-data buffers and the launches of :mod:`rft_mujoco.warp.implicit` (the launch order is in its docstring).

The CPU path's implicit solve (:func:`rft_mujoco.coupling.reference.evaluate_implicit`) is what it ports; the
numbers agree with it on the same state to float32 round-off of MuJoCo Warp's state (tests/test_warp_implicit.py).
"""

from __future__ import annotations

import mujoco
import numpy as np
import warp as wp

from rft_mujoco.warp import implicit as I
from rft_mujoco.warp.implicit_free import Damping, Rows, implicit_free
from rft_mujoco.warp.implicit_law import Law, candidates, law_pass

_IMPLICIT = (int(mujoco.mjtIntegrator.mjINT_IMPLICIT), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))


class ImplicitState:
    """The implicit solve's buffers of one (handle, mujoco_warp Data): world index last, as the explicit path's."""

    def __init__(self, handle, data, st) -> None:
        dev = handle.device
        nworld = st.nworld
        w, b, g, nv, e = nworld, handle.n_bodies, handle.n_groups, handle.nv, handle.n_elements
        n6 = 6 * g
        f8 = wp.float64
        z = lambda shape, dtype=f8: wp.zeros(shape, dtype=dtype, device=dev)  # noqa: E731
        self.e_depth = z((w, e), float)
        self.done, self.lagged, self.use_prior = (z(w, int) for _ in range(3))
        self.redo = z((w, b), int)
        self.prior_flow = wp.array(np.full((g, w), -1, dtype=np.int32), dtype=int, device=dev)
        self.qend = z((1, nv, w))
        self.rest = z((g, w), int)
        self.applied, self.endt, self.start = z((n6, w)), z((n6, w)), z((n6, w))
        self.v_lin, self.v_ang = z((w, b), wp.vec3d), z((w, b), wp.vec3d)
        self.law_wrench = z((w, b), wp.spatial_vectord)
        wk = I.Work()
        for name in ("cap", "weight", "diag0", "rem", "y", "x", "rhs", "order", "kept", "low", "gram", "capacity",
                     "flow"):                   # the explicit rest solve's work, the same shapes (one runs at a time)
            setattr(wk, name, getattr(st, name))
        wk.ridx = st.idx
        for name in ("uprobe", "veff", "wvec", "uf", "wf", "res", "step", "ufull", "lw"):
            setattr(wk, name, z((n6, w)))
        wk.wall, wk.untried, wk.fidx = z((g, w)), z((g, w), int), z((n6, w), int)
        wk.aeff, wk.mat = z((n6, n6, w)), z((n6, n6, w))
        wk.lj, wk.blocks = z((n6, 6, w)), z((n6, 6, w))
        self.work = wk
        njmax = int(data.efc.type.shape[1])
        self.quad = z((njmax, w), int)
        self.const, self.est = z((njmax, w)), z((njmax, w))
        m = handle.mjw_model
        self.rows, self.damping = _rows(m, data, self), _damping(m)
        self.law = _law(handle, m, data, st, self)


def _rows(m, d, ist: ImplicitState) -> Rows:
    r = Rows()
    efc = d.efc
    r.nefc, r.kind, r.id, r.D, r.aref, r.frictionloss = d.nefc, efc.type, efc.id, efc.D, efc.aref, efc.frictionloss
    r.J, r.J_rownnz, r.J_rowadr, r.J_colind = efc.J, efc.J_rownnz, efc.J_rowadr, efc.J_colind
    r.sparse = int(m.is_sparse)
    r.quad, r.fconst, r.est = ist.quad, ist.const, ist.est
    return r


def _damping(m) -> Damping:
    dm = Damping()
    dm.on = 0                                   # set at each evaluation (the integrator, the constraints mode)
    dm.dof_damping, dm.jnt_dofadr = m.dof_damping, m.jnt_dofadr
    dm.trntype, dm.trnid, dm.biastype = m.actuator_trntype, m.actuator_trnid, m.actuator_biastype
    dm.biasprm, dm.gear = m.actuator_biasprm, m.actuator_gear
    return dm


def _law(handle, m, d, st, ist: ImplicitState) -> Law:
    a = handle._a
    lw = Law()
    lw.body_id, lw.elem_body, lw.centroid, lw.normal, lw.area = (a["body_id"], a["elem_body"], a["centroid"],
                                                                 a["normal"], a["area"])
    lw.group_ref, lw.xpos, lw.xmat, lw.xipos, lw.gravity = a["group_ref"], d.xpos, d.xmat, d.xipos, m.opt.gravity
    lw.coef, lw.xi_per_g, lw.mu_surf = a["coef"], st.xi_per_g, st.mu_surf
    lw.no_tension = lw.no_forward = lw.no_power = 0           # the handle's guards, set at each evaluation
    lw.e_depth = ist.e_depth
    return lw


def evaluate_implicit(handle, m, d, st, guards: tuple[int, int, int], blk: int) -> None:
    """The implicit solve of every world of ``d`` (after ``user_part``, ``touch_pass``, ``near_occluders`` and
    ``fwd_actuation``): the bodies' sand wrenches into ``st.sand`` and the diagnostics."""
    if st.implicit is None:                     # solve switched to "implicit" after bind
        st.implicit = ImplicitState(handle, d, st)
    ist = st.implicit
    a, o, dev, nw = handle._a, handle._occ, handle.device, st.nworld
    we = (nw, handle.n_elements)
    wp.launch(candidates, dim=we, device=dev, inputs=[
        a["body_id"], a["elem_body"], a["centroid"], a["area"], st.elem_mask, d.xpos, d.xmat, m.opt.gravity,
        handle._kind, st.flat_height, a["tp"], a["heights"], st.touch, o["occ_start"], o["occ_geom"],
        o["occ_kind"], o["occ_size"], o["occ_rbound"], o["occ_hs_start"], o["occ_hs"], o["margin"], st.near,
        d.geom_xpos, d.geom_xmat, ist.e_depth, st.occluded])
    linearized = int(handle.constraints == "linearized")
    rows, dm, lw = ist.rows, ist.damping, ist.law
    lw.no_tension, lw.no_forward, lw.no_power = guards
    dm.on = int(linearized and int(m.opt.integrator) in _IMPLICIT)
    for p in range(I.ZONE_PASSES if linearized else 1):
        wp.launch(implicit_free, dim=nw, device=dev, block_dim=blk, inputs=[
            p, linearized, handle.mj_model.nbody, a["body_rootid"], a["body_dofnum"], a["body_dofadr"],
            a["body_parentid"], a["dof_parentid"], m.M_rownnz, m.M_rowadr, m.M_colind, m.opt.timestep, dm,
            a["body_id"], a["attached_index"], a["body_group"], a["group_ref"], a["group_radius"], d.time, d.qvel,
            d.qacc, d.qfrc_passive, d.qfrc_bias, d.qfrc_actuator, d.qfrc_applied, d.qfrc_constraint, d.M, d.cdof,
            d.subtree_com, d.xipos, d.xfrc_applied, st.user, st.touch, rows, st.last_time, st.errors, ist.done,
            ist.lagged, ist.use_prior, ist.prior_flow, st.ngroups, st.active, st.slot, st.mf, st.qacc, ist.qend,
            st.jac, st.minv_jt, st.twist, st.free, st.u, st.vs, st.a, st.arm, ist.rest, ist.applied, ist.endt,
            ist.start, ist.v_lin, ist.v_ang, ist.redo, ist.law_wrench, st.count, st.max_depth])
        wp.launch(law_pass, dim=we, device=dev,
                  inputs=[lw, ist.redo, ist.v_lin, ist.v_ang, ist.law_wrench, st.count, st.max_depth])
        wp.launch(I.implicit_solve, dim=nw, device=dev, block_dim=blk, inputs=[
            p, ist.done, st.ngroups, ist.use_prior, ist.prior_flow, st.active, st.slot, a["group_radius"], st.a,
            st.vs, st.u, st.twist, ist.start, ist.law_wrench, st.arm, lw, ist.work, ist.rest, ist.applied,
            ist.endt])
    wp.launch(I.final_twists, dim=nw, device=dev, block_dim=blk, inputs=[
        st.ngroups, st.slot, st.active, a["body_id"], a["group_ref"], d.xipos, ist.rest, st.u, ist.endt, st.arm,
        ist.v_lin, ist.v_ang, ist.redo, ist.law_wrench, st.count, st.max_depth])
    wp.launch(law_pass, dim=we, device=dev,
              inputs=[lw, ist.redo, ist.v_lin, ist.v_ang, ist.law_wrench, st.count, st.max_depth])
    wp.launch(I.implicit_finish, dim=nw, device=dev, block_dim=blk, inputs=[
        st.ngroups, st.active, st.slot, a["group_radius"], a["bound_radius"], st.touch, ist.law_wrench, st.arm,
        ist.rest, ist.applied, ist.prior_flow, st.wrench, st.rft_g, st.size, st.total, st.sand, st.rft, st.scale,
        st.resting, st.status, st.errors])
