"""The implicit solve's free motion on the batched sand (float64, one thread per world):
:func:`rft_mujoco.coupling.reference.implicit_free` and the zone check of
:func:`rft_mujoco.coupling.reference.evaluate_implicit`'s passes.

With ``constraints="linearized"`` the step's motion is ``H qacc = f + J^T W`` with ``H = M + Jq^T D Jq (+ dt
diag(damping) under MuJoCo's implicit integrators)`` and ``f`` the smooth force plus the rows' constant parts
(:mod:`rft_mujoco.warp.system`); with ``"lagged"``, ``H = M`` and ``f`` includes MuJoCo's last constraint force when
the evaluation follows the last one (the explicit path's free motion).
"""

from __future__ import annotations

import mujoco
import warp as wp
from mujoco_warp._src.types import vec10

from rft_mujoco.warp.common import BAD_ACCELERATION, F64
from rft_mujoco.warp.system import add_rows, row_zones
from rft_mujoco.warp.twists import (blend, com_motion, dense_mass, factor_solve, follows, mobility, smooth_force,
                                    touching_groups)

wp.set_module_options({"enable_backward": False})      # forward only: no adjoints to compile

TRN_JOINT = wp.constant(int(mujoco.mjtTrn.mjTRN_JOINT))
BIAS_AFFINE = wp.constant(int(mujoco.mjtBias.mjBIAS_AFFINE))


@wp.struct
class Rows:
    """This step's constraint rows of MuJoCo Warp (``d.efc``, ``d.nefc``) and their zones (world index last)."""

    nefc: wp.array(dtype=int)
    kind: wp.array2d(dtype=int)
    id: wp.array2d(dtype=int)
    D: wp.array2d(dtype=float)
    aref: wp.array2d(dtype=float)
    frictionloss: wp.array2d(dtype=float)
    J: wp.array3d(dtype=float)
    J_rownnz: wp.array2d(dtype=int)
    J_rowadr: wp.array2d(dtype=int)
    J_colind: wp.array3d(dtype=int)
    sparse: int
    quad: wp.array2d(dtype=int)
    fconst: wp.array2d(dtype=F64)
    est: wp.array2d(dtype=F64)


@wp.struct
class Damping:
    """The damping MuJoCo's implicit integrators treat implicitly (reference.velocity_damping): the model's
    arrays, read at every evaluation; ``on`` = 0 under Euler and RK4."""

    on: int
    dof_damping: wp.array2d(dtype=float)
    jnt_dofadr: wp.array(dtype=int)
    trntype: wp.array(dtype=int)
    trnid: wp.array(dtype=wp.vec2i)
    biastype: wp.array(dtype=int)
    biasprm: wp.array2d(dtype=vec10)
    gear: wp.array2d(dtype=wp.spatial_vector)


@wp.func
def _add_damping(w: int, nv: int, dt: F64, dm: Damping, mf: wp.array3d(dtype=F64)):
    """mf[i, i, w] += dt (dof damping + the velocity gain of affine actuators on a joint times gear^2)."""
    for i in range(nv):
        mf[i, i, w] = mf[i, i, w] + dt * F64(dm.dof_damping[w % dm.dof_damping.shape[0], i])
    for k in range(dm.trntype.shape[0]):
        if dm.trntype[k] == TRN_JOINT and dm.biastype[k] == BIAS_AFFINE:
            dof = dm.jnt_dofadr[dm.trnid[k][0]]
            g = F64(dm.gear[w % dm.gear.shape[0], k][0])
            kv = -F64(dm.biasprm[w % dm.biasprm.shape[0], k][2])
            mf[dof, dof, w] = mf[dof, dof, w] + dt * kv * g * g


@wp.func
def _zones(w: int, nv: int, rows: Rows, qacc: wp.array3d(dtype=F64), use_prev: int):
    return row_zones(w, rows.nefc[w], rows.kind, rows.id, rows.D, rows.aref, rows.frictionloss, rows.J,
                     rows.J_rownnz, rows.J_rowadr, rows.J_colind, rows.sparse, nv, qacc, use_prev, rows.quad,
                     rows.fconst, rows.est)


@wp.kernel
def implicit_free(
        pass_index: int, linearized: int,
        # model
        nbody: int, body_rootid: wp.array(dtype=int), body_dofnum: wp.array(dtype=int),
        body_dofadr: wp.array(dtype=int), body_parentid: wp.array(dtype=int), dof_parentid: wp.array(dtype=int),
        M_rownnz: wp.array(dtype=int), M_rowadr: wp.array(dtype=int), M_colind: wp.array(dtype=int),
        timestep: wp.array(dtype=float), dm: Damping,
        # the handle
        body_id: wp.array(dtype=int), attached_index: wp.array(dtype=int), body_group: wp.array(dtype=int),
        group_ref: wp.array(dtype=int), group_radius: wp.array(dtype=F64),
        # MuJoCo Warp data
        time: wp.array(dtype=float), qvel: wp.array2d(dtype=float), qacc_last: wp.array2d(dtype=float),
        qfrc_passive: wp.array2d(dtype=float), qfrc_bias: wp.array2d(dtype=float),
        qfrc_actuator: wp.array2d(dtype=float), qfrc_applied: wp.array2d(dtype=float),
        qfrc_constraint: wp.array2d(dtype=float), M: wp.array2d(dtype=float),
        cdof: wp.array2d(dtype=wp.spatial_vector), subtree_com: wp.array2d(dtype=wp.vec3),
        xipos: wp.array2d(dtype=wp.vec3), xfrc: wp.array2d(dtype=wp.spatial_vector),
        user: wp.array2d(dtype=wp.spatial_vector), touch: wp.array2d(dtype=int), rows: Rows,
        # state and outputs
        last_time: wp.array(dtype=float), errors: wp.array(dtype=int), done: wp.array(dtype=int),
        lagged: wp.array(dtype=int), use_prior: wp.array(dtype=int), prior_flow: wp.array2d(dtype=int),
        ngroups: wp.array(dtype=int), active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
        mf: wp.array3d(dtype=F64), qacc: wp.array3d(dtype=F64), qend: wp.array3d(dtype=F64),
        jac: wp.array3d(dtype=F64), minv_jt: wp.array3d(dtype=F64), twist: wp.array2d(dtype=F64),
        free: wp.array2d(dtype=F64), u: wp.array2d(dtype=F64), vs: wp.array2d(dtype=F64), a: wp.array3d(dtype=F64),
        arm: wp.array2d(dtype=wp.vec3d), rest: wp.array2d(dtype=int), applied: wp.array2d(dtype=F64),
        endt: wp.array2d(dtype=F64), start: wp.array2d(dtype=F64), v_lin: wp.array2d(dtype=wp.vec3d),
        v_ang: wp.array2d(dtype=wp.vec3d), redo: wp.array2d(dtype=int),
        law_wrench: wp.array2d(dtype=wp.spatial_vectord), count: wp.array2d(dtype=int),
        max_depth: wp.array2d(dtype=float)):
    """One thread per world, a zone pass: at pass 0 the touching groups and whether this evaluation follows the
    last one; at later passes the rows' zones at the last solve's end accelerations (the world is ``done`` when
    none changed) and the twists its flowing groups start from. Then the free motion, the scaled mobility, the
    probe twists ``u`` and their motions at the touching bodies' COMs (``v_lin``, ``v_ang``); ``redo[w, b]`` 1
    for the touching bodies of a world that computed them (their law wrench, count and depth zeroed for the law
    pass), 0 elsewhere."""
    w = wp.tid()
    nb = body_id.shape[0]
    if pass_index == 0 or done[w] == 0:
        for b in range(nb):
            redo[w, b] = 0
    nv = qvel.shape[1]
    dt = F64(timestep[w % timestep.shape[0]])
    if pass_index == 0:
        done[w] = 0
        lagged[w] = follows(w, time, last_time, dt)
        ng0 = touching_groups(w, touch, body_group, group_ref.shape[0], active, slot)
        ngroups[w] = ng0
        same = lagged[w]
        for g in range(group_ref.shape[0]):
            now = int(0)
            for r in range(ng0):
                if active[r, w] == g:
                    now = 1
            if (prior_flow[g, w] >= 0) != (now == 1):
                same = 0
        use_prior[w] = same
        if ng0 == 0:
            done[w] = 1
            return
    elif done[w] != 0:
        return
    ng = ngroups[w]
    n6 = 6 * ng
    if pass_index > 0:
        for j in range(nv):
            s = qacc[0, j, w]
            for i in range(n6):
                s += minv_jt[i, j, w] * applied[i, w]
            qend[0, j, w] = s
        if _zones(w, nv, rows, qend, 1) == 0:
            done[w] = 1
            return
        for r in range(ng):
            for c in range(6):
                i = 6 * r + c
                start[i, w] = endt[i, w]
                if rest[r, w] != 0:
                    start[i, w] = twist[i, w]
    lag_q = int(0)
    if linearized == 0:
        lag_q = lagged[w]
    smooth_force(w, nbody, lag_q, body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid,
                 attached_index, qfrc_passive, qfrc_bias, qfrc_actuator, qfrc_applied, qfrc_constraint, cdof,
                 subtree_com, xipos, xfrc, user, qacc)
    dense_mass(w, nv, M_rownnz, M_rowadr, M_colind, M, mf)
    if linearized != 0:
        if pass_index == 0:
            for j in range(nv):
                qend[0, j, w] = F64(qacc_last[w, j])
            _zones(w, nv, rows, qend, 0)
        add_rows(w, rows.nefc[w], rows.D, rows.aref, rows.J, rows.J_rownnz, rows.J_rowadr, rows.J_colind,
                 rows.sparse, nv, rows.quad, rows.fconst, mf, qacc)
        if dm.on != 0:
            _add_damping(w, nv, dt, dm, mf)
    if factor_solve(w, nv, mf, qacc) == 0:
        errors[w] = errors[w] | BAD_ACCELERATION
        ngroups[w] = 0
        done[w] = 1
        return
    mobility(w, ng, dt, body_id, group_ref, group_radius, active, body_rootid, body_dofnum, body_dofadr,
             body_parentid, dof_parentid, qvel, cdof, subtree_com, xipos, mf, qacc, jac, minv_jt, twist, free, vs, a)
    blend(w, ng, active, group_radius, twist, free, u)
    for b in range(nb):
        r = slot[b, w]
        if r < 0:
            continue
        lin, om = com_motion(w, b, r, body_id, group_ref, active, xipos, u, arm)
        v_lin[w, b] = lin
        v_ang[w, b] = om
        redo[w, b] = 1
        law_wrench[w, b] = wp.spatial_vectord()
        count[w, b] = 0
        max_depth[w, b] = 0.0
