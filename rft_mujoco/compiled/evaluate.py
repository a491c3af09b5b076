"""The compiled evaluation of one sand handle on one MjData, on three argument tuples.

What ``SandHandle`` computes in numpy (:mod:`rft_mujoco.coupling.handle`, the reference the tests compare
with), compiled, in two phases around MuJoCo's actuation (MuJoCo computes actuator forces only after
``mjcb_control``, so the caller runs ``mj_fwdActuation`` between them, and only when a body touches):

1. :func:`broadphase`: time continuity (whether MuJoCo's previous constraint solve belongs to this motion),
   gravity, the bodies that touch the sand and their poses and velocities;
2. :func:`evaluate`: the rest treatment (:mod:`rft_mujoco.physics.rest`) or the naive force, the diagnostics,
   the wrenches added into the caller's sum.

Arguments come as tuples whose order is fixed by the schemas below, so that the Python path (one numba
call per phase) and the native route (:mod:`rft_mujoco.compiled.route`, one call for every handle of a
model) run this very code, inlined into the route's phases (plain calls with the tuples cost 2 us, measured)
but for :func:`evaluate_rest`, the route's own C function; the Python path's copy compiles at its first use:

* ``md`` (:data:`MJDATA_FIELDS`): MjData arrays (views, never copied);
* ``hc`` (:data:`HANDLE_FIELDS`): the handle's constants, ``gravity`` a live view of ``model.opt.gravity``
  and ``params`` (:data:`PARAMS`) the settings that may change between steps;
* ``ws`` (:data:`WORK_FIELDS`): the per-(handle, MjData) buffers, the diagnostics among them, and
  ``state`` (:data:`STATE`).
"""

from __future__ import annotations

import math

import numpy as np

from rft_mujoco import tol
from rft_mujoco.compiled.element_pass import (REUSE_COLUMNS, REUSE_VALID, SCRATCH_ROWS, law_of, occluders_of, surface_of,
                                           terrain_of, wrenches)
from rft_mujoco.compiled.elements import finish_naive, touching
from rft_mujoco.compiled.jit import INLINE, JIT, njit
from rft_mujoco.compiled.locks import lock_matrices, locked_rest, stuck_dofs
from rft_mujoco.compiled import schema as sc
from rft_mujoco.compiled.schema import HANDLE_FIELDS, MJDATA_FIELDS, PARAMS, STATE, WORK_FIELDS  # noqa: F401
from rft_mujoco.compiled.rest import _chain_dof, add_user_wrenches, blend, rest_wrenches, solve_m
from rft_mujoco.compiled.share import (BAD_ACCELERATION, NOT_FINITE, NOT_FINITE_STATE,  # noqa: F401
                                       _clear, _share_and_commit, body_arms, group_sums, group_twists,
                                       touching_groups)

_TIME_SLACK = 1.0 + tol.TIME_RTOL
"""A step of dt (1 + TIME_RTOL) still follows the previous evaluation (frozen into the compiled code)."""

FRICTION_FIELDS = (("efc_type", "i4"), ("efc_id", "i4"), ("efc_D", "f8"), ("efc_aref", "f8"),
                   ("efc_frictionloss", "f8"), ("qacc", "f8"))
"""(name, dtype) of the ``fr`` tuple: MjData's constraint rows of this step (they move with ``nefc``, so
the Python path reads them at every call and the native route from ``mjData``'s pointers) and its
``qacc`` (the last solve's accelerations)."""


def build_workspace(n_bodies: int, n_groups: int, nv: int, n_rows: int) -> dict:
    """Zeroed arrays of :data:`WORK_FIELDS` for B bodies, G groups, nv dofs; ``n_rows``: scratch columns."""
    b, g, n6, nv1 = n_bodies, n_groups, 6 * n_groups, max(nv, 1)
    shapes = dict(
        touch=(b,), body_pos=(b, 3), body_mat=(b, 9), body_com=(b, 3), v_com=(b, 3), omega=(b, 3),
        scratch=(SCRATCH_ROWS, n_rows), wrench=(b, 6), count=(b,), depth=(b,), occluded=(b,), active=(g,),
        slot=(b,), idx=(n6,), rest=(g,), flow=(g,), zt=(max(nv, 1), max(n6, 1)), minv_jt=(max(n6, 6), nv), mob=(n6, n6),
        a=(n6, n6), block=(n6, n6), qacc=(nv,), v=(n6,), rhs=(n6,), weight=(n6,), twist=(g, 6), free=(g, 6),
        u=(g, 6), rft_g=(g, 6), w=(g, 6), cap=(g, 6), u_lin=(b, 3), u_ang=(b, 3), arm=(b, 3), applied=(b, 6),
        size=(b,), total=(g,), force=(b, 3), torque=(b, 3), submerged=(b,), max_depth=(b,), scale=(b,),
        rft_force=(b, 3), resting=(b,), occluded_area=(b,), state=(len(STATE),), lin=(3 * n6 + 5, max(n6, 1)),
        perm=(2 * n6,), x=(n6,), index=(2, n_rows), chain=(g, nv + 1), keep_active=(g,), keep_rest=(g,),
        lock_i=(3, nv1), lock_f=(5, nv1), lock_z=(nv1, nv1), lock_chain=(nv1, nv1 + 1), lock_s=(nv1, nv1),
        lock_c=(nv1, max(n6, 1)), lock_r=(nv1, nv1), lock_x=(nv1, max(n6, 1)), lock_mob=(n6, n6), lock_free=(g, 6),
        lock_w=(g, 6), lock_rest=(g,), group_tree=(g,), lock_prev=(nv1,), reuse=(b, REUSE_COLUMNS))
    dtype = {"i": np.int64, "f": np.float64, "b": np.bool_}
    out = {name: np.zeros(shapes[name], dtype=dtype[kind[0]]) for name, kind in WORK_FIELDS}
    out["scale"][:] = 1.0
    out["state"][[sc.S_LAST_TIME, sc.S_CLEAN, sc.S_KEPT_RANK]] = (-math.inf, 1.0, -1.0)
    return out


@njit(**JIT)
def _gravity(gravity):
    """(g_hat (3,) tuple, |g|) of a gravity vector; |g| = 0 is the caller's error (checked at attach)."""
    mag = math.sqrt(gravity[0] * gravity[0] + gravity[1] * gravity[1] + gravity[2] * gravity[2])
    return gravity[0] / mag, gravity[1] / mag, gravity[2] / mag, mag


@njit(**INLINE)
def broadphase(md, hc, ws, time, dt):
    """Phase 1: the time, the touching bodies (their count in ``state[S_TOUCHING]``; none: the diagnostics
    cleared once). Returns the count, or NOT_FINITE_STATE."""
    xpos, xmat, xipos, cvel = md[sc.M_XPOS], md[sc.M_XMAT], md[sc.M_XIPOS], md[sc.M_CVEL]
    subtree_com, qpos, qvel = md[sc.M_SUBTREE_COM], md[sc.M_QPOS], md[sc.M_QVEL]
    ids, root, bound_center, bound_radius = hc[sc.H_IDS], hc[sc.H_ROOT], hc[sc.H_BOUND_CENTER], hc[sc.H_BOUND_RADIUS]
    gravity = hc[sc.H_GRAVITY]
    touch, body_pos, body_mat, body_com = ws[sc.W_TOUCH], ws[sc.W_BODY_POS], ws[sc.W_BODY_MAT], ws[sc.W_BODY_COM]
    v_com, omega = ws[sc.W_V_COM], ws[sc.W_OMEGA]
    state = ws[sc.W_STATE]
    state[sc.S_EVALUATIONS] += 1.0
    if state[sc.S_RK4_STAGE] < 2.0:                    # not a later RK4 stage: nothing kept from an earlier evaluation
        state[sc.S_KEPT_GROUPS] = 0.0
        state[sc.S_KEPT_RANK] = -1.0
    step = time - state[sc.S_LAST_TIME]
    state[sc.S_LAGGED] = 1.0 if 0.0 <= step <= dt * _TIME_SLACK else 0.0         # coupling._Workspace.follow_time
    state[sc.S_LAST_TIME] = time
    g0, g1, g2, _ = _gravity(gravity)
    g_hat = np.array((g0, g1, g2))
    k = touching((ids, root, bound_center, bound_radius), (xpos, xmat, xipos, cvel, subtree_com, qpos, qvel),
                 surface_of(hc), terrain_of(hc, g_hat), (touch, body_pos, body_mat, body_com, v_com, omega))
    if k < 0:
        return NOT_FINITE_STATE
    state[sc.S_TOUCHING] = k
    if k == 0 and state[sc.S_CLEAN] == 0.0:
        _clear(ws[sc.W_FORCE], ws[sc.W_TORQUE], ws[sc.W_SUBMERGED], ws[sc.W_MAX_DEPTH], ws[sc.W_SCALE],
               ws[sc.W_RFT_FORCE], ws[sc.W_RESTING], ws[sc.W_OCCLUDED_AREA])
        state[sc.S_CLEAN] = 1.0
    return k


@njit(**INLINE)
def evaluate(md, hc, ws, user_xfrc, dt, sand_out, fr):
    """Phase 2 (after ``mj_fwdActuation``), for the ``state[sc.S_TOUCHING] > 0`` touching bodies of :func:`broadphase`
    (:func:`evaluate_rest` with the rest treatment, else :func:`evaluate_naive`): the sand wrenches, the
    diagnostics, and the wrenches added to ``sand_out`` (nbody, 6) at their bodies' rows. ``user_xfrc``
    (nbody, 6): the user's own xfrc_applied (enters the free motion); ``fr`` (:data:`FRICTION_FIELDS`): this
    step's constraint rows and MuJoCo's last ``qacc``. Returns 1 (a non-zero wrench), 0 (none), NOT_FINITE or
    BAD_ACCELERATION (nothing written)."""
    if hc[sc.H_PARAMS][7] != 0.0:
        return evaluate_rest(md, hc, ws, user_xfrc, dt, sand_out, fr)
    return evaluate_naive(md, hc, ws, sand_out)


@njit(**INLINE)
def evaluate_rest(md, hc, ws, user_xfrc, dt, sand_out, fr):
    """:func:`evaluate` with the rest treatment (the route's own C function: ``route.rest_phase``)."""
    state = ws[sc.W_STATE]
    state[sc.S_CLEAN] = 0.0
    g0, g1, g2, g_mag = _gravity(hc[sc.H_GRAVITY])
    return _rest(md, hc, ws, user_xfrc, dt, sand_out, fr, int(state[sc.S_TOUCHING]), np.array((g0, g1, g2)),
                 hc[sc.H_PARAMS][1] * g_mag, state[sc.S_LAGGED] != 0.0)


@njit(**INLINE)
def evaluate_naive(md, hc, ws, sand_out):
    """:func:`evaluate` without the rest treatment: the published force at the element velocities."""
    state = ws[sc.W_STATE]
    k = int(state[sc.S_TOUCHING])
    state[sc.S_CLEAN] = 0.0
    g0, g1, g2, g_mag = _gravity(hc[sc.H_GRAVITY])
    g_hat = np.array((g0, g1, g2))
    params = hc[sc.H_PARAMS]
    xi_n = params[sc.P_XI_PER_G] * g_mag
    wrenches(ws[sc.W_TOUCH], k, surface_of(hc), (ws[sc.W_BODY_POS], ws[sc.W_BODY_MAT], ws[sc.W_BODY_COM]),
             (ws[sc.W_V_COM], ws[sc.W_OMEGA]), terrain_of(hc, g_hat), law_of(hc, xi_n), occluders_of(hc, md),
             (ws[sc.W_SCRATCH], ws[sc.W_INDEX]), (ws[sc.W_WRENCH], ws[sc.W_COUNT], ws[sc.W_DEPTH], ws[sc.W_OCCLUDED]),
             0.0)
    return finish_naive((ws[sc.W_WRENCH], ws[sc.W_COUNT], ws[sc.W_DEPTH], ws[sc.W_OCCLUDED], ws[sc.W_V_COM],
                         ws[sc.W_OMEGA], ws[sc.W_TOUCH]), k, hc[sc.H_IDS], params[sc.P_PASSIVE] != 0.0,
                        (ws[sc.W_FORCE], ws[sc.W_TORQUE], ws[sc.W_SUBMERGED], ws[sc.W_MAX_DEPTH], ws[sc.W_SCALE],
                         ws[sc.W_RFT_FORCE], ws[sc.W_RESTING], ws[sc.W_OCCLUDED_AREA]), sand_out)


@njit(**INLINE)
def _mobility(groups, kinematics, qacc, tree, factor, dt, chain, zt, out, blocks):
    """For the reference bodies of the active groups 0..ng-1 (``groups`` = (``ng``, ``active``, ``ids``,
    ``group_ref``)): twists (now, and free: after ``dt`` at ``qacc``) and the mobility ``mob = J M^-1 J^T``
    (6 ng, 6 ng), with the kinematic tree's sparsity; ``out`` = (``twist``, ``free``, ``mob``). ``kinematics`` =
    MjData's (``xipos``, ``cdof``, ``subtree_com``, ``qvel``), ``tree``: :data:`rft_mujoco.compiled.rest.JAC_TREE`,
    ``factor``: :data:`rft_mujoco.compiled.locks.FACTOR` (MuJoCo's ``qLD``).

    A body's Jacobian is zero outside its chain of dofs (``chain[r, 1:1 + chain[r, 0]]``, from the body to
    the root). With MuJoCo's factor ``M = L^T D L``, ``J M^-1 J^T = Z^T D^-1 Z`` where ``Z = L^-T J^T``:
    the first half of ``solve_m``, which keeps every column of ``Z`` on its body's chain (columns
    ``6 r..6 r + 5`` of ``zt`` (nv, 6 ng); only their chain rows are written and read), scaled to
    ``W = D^-1/2 Z`` so that every entry is a sum of products of two W entries (exactly symmetric). A block
    (r, s) sums over the dofs the two chains share: the part of both next to the root. Without ``blocks``
    only the twists are computed (``mob`` is kept)."""
    ng, active, ids, group_ref = groups
    xipos, cdof, subtree_com, qvel = kinematics
    body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid = tree
    rownnz, rowadr, colind, qld, qld_diag_inv = factor
    twist, free, mob = out
    for r in range(ng):
        b = ids[group_ref[active[r]]]
        rt = body_rootid[b]
        dx = xipos[b, 0] - subtree_com[rt, 0]
        dy = xipos[b, 1] - subtree_com[rt, 1]
        dz = xipos[b, 2] - subtree_com[rt, 2]
        n = 0
        j = _chain_dof(b, body_dofnum, body_dofadr, body_parentid)
        i0 = 6 * r
        v0 = v1 = v2 = v3 = v4 = v5 = 0.0            # J qvel and J qacc, one accumulator per component
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0
        while j >= 0:                                # the Jacobian (as rest.jacobian), chain rows only
            chain[r, 1 + n] = j
            n += 1
            wx, wy, wz = cdof[j, 0], cdof[j, 1], cdof[j, 2]
            j0 = cdof[j, 3] + (wy * dz - wz * dy)
            j1 = cdof[j, 4] + (wz * dx - wx * dz)
            j2 = cdof[j, 5] + (wx * dy - wy * dx)
            zt[j, i0] = j0
            zt[j, i0 + 1] = j1
            zt[j, i0 + 2] = j2
            zt[j, i0 + 3] = wx
            zt[j, i0 + 4] = wy
            zt[j, i0 + 5] = wz
            qv, qa = qvel[j], qacc[j]
            v0 += j0 * qv
            v1 += j1 * qv
            v2 += j2 * qv
            v3 += wx * qv
            v4 += wy * qv
            v5 += wz * qv
            a0 += j0 * qa
            a1 += j1 * qa
            a2 += j2 * qa
            a3 += wx * qa
            a4 += wy * qa
            a5 += wz * qa
            j = dof_parentid[j]
        chain[r, 0] = n
        twist[r, 0], twist[r, 1], twist[r, 2], twist[r, 3], twist[r, 4], twist[r, 5] = v0, v1, v2, v3, v4, v5
        free[r, 0] = v0 + dt * a0
        free[r, 1] = v1 + dt * a1
        free[r, 2] = v2 + dt * a2
        free[r, 3] = v3 + dt * a3
        free[r, 4] = v4 + dt * a4
        free[r, 5] = v5 + dt * a5
        if not blocks:
            continue
        for u in range(n):                           # Z = L^-T J^T, from the body towards the root
            j = chain[r, 1 + u]
            a0_ = rowadr[j]
            for a in range(a0_, a0_ + rownnz[j] - 1):
                p = colind[a]
                q = qld[a]
                for c in range(6):
                    zt[p, i0 + c] -= q * zt[j, i0 + c]
        for u in range(n):                           # W = D^-1/2 Z
            j = chain[r, 1 + u]
            d = math.sqrt(qld_diag_inv[j])
            for c in range(6):
                zt[j, i0 + c] *= d
    if not blocks:
        return
    for r in range(ng):
        nr = chain[r, 0]
        i0 = 6 * r
        for s_ in range(r + 1):
            ns = chain[s_, 0]
            j0 = 6 * s_
            for i in range(6):
                for c in range(6):
                    mob[i0 + i, j0 + c] = 0.0
            t = 0
            while t < nr and t < ns and chain[r, nr - t] == chain[s_, ns - t]:
                j = chain[r, nr - t]
                for i in range(6):
                    y = zt[j, i0 + i]
                    for c in range(6):
                        mob[i0 + i, j0 + c] += y * zt[j, j0 + c]
                t += 1
            if s_ < r:
                for i in range(6):
                    for c in range(6):
                        mob[j0 + c, i0 + i] = mob[i0 + i, j0 + c]


@njit(**INLINE)
def _rest(md, hc, ws, user_xfrc, dt, sand_out, fr, k, g_hat, xi_n, lagged):
    """The rest treatment of the ``k`` touching bodies: ``SandHandle._evaluate_rest``."""
    xipos, cdof, subtree_com, qvel = md[sc.M_XIPOS], md[sc.M_CDOF], md[sc.M_SUBTREE_COM], md[sc.M_QVEL]
    qfrc_passive, qfrc_bias, qfrc_actuator = md[sc.M_QFRC_PASSIVE], md[sc.M_QFRC_BIAS], md[sc.M_QFRC_ACTUATOR]
    qfrc_applied, qfrc_constraint = md[sc.M_QFRC_APPLIED], md[sc.M_QFRC_CONSTRAINT]
    qld, qld_diag_inv = md[sc.M_QLD], md[sc.M_QLDIAGINV]
    ids, group_of, group_ref = hc[sc.H_IDS], hc[sc.H_GROUP_OF], hc[sc.H_GROUP_REF]
    body_rootid, body_dofnum, body_dofadr = hc[sc.H_BODY_ROOTID], hc[sc.H_BODY_DOFNUM], hc[sc.H_BODY_DOFADR]
    body_parentid, dof_parentid = hc[sc.H_BODY_PARENTID], hc[sc.H_DOF_PARENTID]
    rownnz, rowadr, colind = hc[sc.H_M_ROWNNZ], hc[sc.H_M_ROWADR], hc[sc.H_M_COLIND]
    group_radius, settings = hc[sc.H_GROUP_RADIUS], hc[sc.H_SETTINGS]
    touch, body_com = ws[sc.W_TOUCH], ws[sc.W_BODY_COM]
    count, depth_max, occluded = ws[sc.W_COUNT], ws[sc.W_DEPTH], ws[sc.W_OCCLUDED]
    active, slot, idx, rest, flow = ws[sc.W_ACTIVE], ws[sc.W_SLOT], ws[sc.W_IDX], ws[sc.W_REST], ws[sc.W_FLOW]
    zt, minv_jt, mob, a, block = ws[sc.W_ZT], ws[sc.W_MINV_JT], ws[sc.W_MOB], ws[sc.W_A], ws[sc.W_BLOCK]
    qacc, v, rhs, weight = ws[sc.W_QACC], ws[sc.W_V], ws[sc.W_RHS], ws[sc.W_WEIGHT]
    twist, free, u, rft_g, w, cap = ws[sc.W_TWIST], ws[sc.W_FREE], ws[sc.W_U], ws[sc.W_RFT_G], ws[sc.W_W], ws[sc.W_CAP]
    u_lin, u_ang, arm, size = ws[sc.W_U_LIN], ws[sc.W_U_ANG], ws[sc.W_ARM], ws[sc.W_SIZE]
    total = ws[sc.W_TOTAL]
    wrench = ws[sc.W_WRENCH]
    nv = qvel.shape[0]
    # 1. the touching groups, in increasing group order, and each touching body's row among them
    ng_all = group_ref.shape[0]
    ng = touching_groups(k, touch, group_of, ng_all, rest, active, slot)
    # 2. free acceleration: smooth forces (+ the previous constraint forces) + the user's wrenches, M^-1
    for i in range(nv):
        f = qfrc_passive[i] - qfrc_bias[i] + qfrc_actuator[i] + qfrc_applied[i]
        qacc[i] = f + qfrc_constraint[i] if lagged else f
    add_user_wrenches(user_xfrc, xipos, cdof, subtree_com,
                      (body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid), minv_jt, qacc)
    solve_m(rownnz, rowadr, colind, qld, qld_diag_inv, qacc)
    for i in range(nv):
        if not math.isfinite(qacc[i]):
            return BAD_ACCELERATION
    # 3. the dofs their dry friction held in MuJoCo's last solve (reference.stuck_dofs); Jacobians of the
    #    reference points, twists now and free, mobility J M^-1 J^T (_mobility): at a later RK4 stage with
    #    the same touching groups and no such dof, an earlier stage's mobility (reference.StepKeep)
    lock_i, lock_f = ws[sc.W_LOCK_I], ws[sc.W_LOCK_F]
    nl = 0
    if lagged:
        nl = stuck_dofs(fr, ng, active, ids, group_ref, (body_dofnum, body_dofadr, body_parentid, dof_parentid),
                        lock_i, lock_f, ws[sc.W_GROUP_TREE])
    state = ws[sc.W_STATE]
    keep_active, keep_rest = ws[sc.W_KEEP_ACTIVE], ws[sc.W_KEEP_REST]
    frozen = state[sc.S_RK4_STAGE] >= 2.0 and state[sc.S_KEPT_GROUPS] == ng and nl == 0
    for r in range(ng):
        frozen = frozen and keep_active[r] == active[r]
    if frozen:
        state[sc.S_KEPT_EVALUATIONS] += 1.0
    else:
        state[sc.S_KEPT_GROUPS] = ng if state[sc.S_RK4_STAGE] >= 1.0 and nl == 0 else 0.0
        state[sc.S_KEPT_RANK] = -1.0
        for r in range(ng):
            keep_active[r] = active[r]
    _mobility((ng, active, ids, group_ref), (xipos, cdof, subtree_com, qvel), qacc,
              (body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid), (rownnz, rowadr, colind, qld,
              qld_diag_inv), dt, ws[sc.W_CHAIN], zt, (twist, free, mob), not frozen)
    lock = (lock_i, lock_f, ws[sc.W_LOCK_Z], ws[sc.W_LOCK_CHAIN], ws[sc.W_LOCK_S], ws[sc.W_LOCK_C], ws[sc.W_LOCK_R],
            ws[sc.W_LOCK_X], ws[sc.W_LOCK_MOB], ws[sc.W_LOCK_FREE], ws[sc.W_LOCK_W], ws[sc.W_LOCK_REST])  # locks.LOCK
    if nl > 0:
        lock_matrices(nl, (rownnz, rowadr, colind, qld, qld_diag_inv), qacc, dof_parentid, lock)
    # 4. blended twists (rest.blend), moved to each touching body's COM
    rad_g = total                                   # (G,) reuses ``total`` as the active groups' radii
    for r in range(ng):
        rad_g[r] = group_radius[active[r]]
    blend(twist, free, rad_g, ng, u)
    body_arms(k, slot, (active, ids, group_ref), body_com, xipos, arm)
    group_twists(u, None, k, slot, arm, u_lin, u_ang, None)
    # 5. RFT wrenches at the blended twists; the groups' wrenches about their reference points
    reuse = ws[sc.W_REUSE]
    if not lagged:                                  # a reset or a jump in time: nothing is reused across it
        for j in range(reuse.shape[0]):
            reuse[j, REUSE_VALID] = 0.0
    state[sc.S_REUSED_WRENCHES] += wrenches(
        touch, k, surface_of(hc), (ws[sc.W_BODY_POS], ws[sc.W_BODY_MAT], body_com), (u_lin, u_ang), terrain_of(hc, g_hat),
        law_of(hc, xi_n), occluders_of(hc, md), (ws[sc.W_SCRATCH], ws[sc.W_INDEX]), (wrench, count, depth_max, occluded),
        0.0, (reuse, hc[sc.H_PARAMS][sc.P_REUSE_TOL]))
    group_sums(ng, None, k, slot, arm, None, wrench, rft_g)
    # 6. the rest solve (rest.rest_wrenches), in the groups' radii
    state[sc.S_LOCKED_DOFS] = 0.0
    lock_prev = ws[sc.W_LOCK_PREV]                               # the dofs locked in the last evaluation
    sticky = False
    for l in range(nl):
        sticky = sticky or lock_prev[lock_i[0, l]]
    for j in range(lock_prev.shape[0]):
        lock_prev[j] = False
    groups, out = (free, mob, rft_g, u, rad_g), (w, rest)                        # rest.REST_GROUPS, REST_OUT
    work = (a, v, cap, flow, idx, block, rhs, size, weight, ws[sc.W_LIN], ws[sc.W_PERM], ws[sc.W_X])  # REST_WORK
    if nl > 0:
        state[sc.S_LOCKED_DOFS] = locked_rest(nl, groups, dt, ng, settings, out, work, (keep_rest, state),
                                              (twist, ws[sc.W_CHAIN], zt), lock, not sticky)
        for l in range(nl):
            if lock_i[1, l] != 0:
                lock_prev[lock_i[0, l]] = True
        state[sc.S_LOCKED_EVALUATIONS] += 1.0 if state[sc.S_LOCKED_DOFS] > 0.0 else 0.0
    else:
        rest_wrenches(groups, dt, ng, settings, out, work, (keep_rest, state), frozen)
    # 7. each body's part (coupling._share); 8. diagnostics and the wrenches into sand_out (SandHandle._commit)
    return _share_and_commit(k, ng, (rad_g, rft_g, w, rest), hc, ws, sand_out)


def params_array(max_height: float, xi_per_g: float, mu_surf: float, guards, kind: int, stabilize: bool,
                 passive: bool, margin: float, monitor_every: int = 0, rk4_evaluated: int = 4,
                 reuse_tol: float = 0.0, out=None) -> np.ndarray:
    """``hc.params`` (:data:`PARAMS`), written into ``out`` when given (a live handle's array)."""
    values = (max_height, xi_per_g, mu_surf, float(guards.no_tension), float(guards.no_forward_tangential),
              float(guards.no_positive_power), float(kind), float(stabilize), float(passive), margin,
              float(monitor_every), float(rk4_evaluated), float(reuse_tol))
    if out is None:
        return np.array(values, dtype=np.float64)
    out[:] = values
    return out


def handle_constants(model, layout, packed, spec, coef, tol, settings, params) -> tuple:
    """The ``hc`` tuple (:data:`HANDLE_FIELDS`) of a handle: its arrays and the model's (``model.opt.gravity``
    as a live view, so gravity changes are seen). ``layout``: the handle's
    :class:`rft_mujoco.coupling.layout.Layout` (bodies, roots, groups, bounding spheres, occluders); ``packed``
    its elements packed in clusters (:func:`rft_mujoco.compiled.elements.pack`); ``spec`` the terrain's kernel
    spec."""
    i8 = lambda a: np.ascontiguousarray(a, dtype=np.int64)        # noqa: E731
    f8 = lambda a: np.ascontiguousarray(a, dtype=np.float64)      # noqa: E731
    kind, tp, heights = spec
    body_ids, root, groups, occluders = layout.body_ids, layout.root, layout.groups, layout.occluders
    bound_center, bound_radius = layout.bound_center, layout.bound_radius
    arrays = dict(
        ids=i8(body_ids), root=i8(root), group_of=i8(groups.of_body), group_ref=i8(groups.ref),
        cluster_start=packed.cluster_start, body_clusters=packed.body_clusters,
        body_rootid=i8(model.body_rootid), body_dofnum=i8(model.body_dofnum), body_dofadr=i8(model.body_dofadr),
        body_parentid=i8(model.body_parentid), dof_parentid=i8(model.dof_parentid), M_rownnz=i8(model.M_rownnz),
        M_rowadr=i8(model.M_rowadr), M_colind=i8(model.M_colind), occ_start=occluders.start,
        occ_geom=occluders.geom, occ_kind=occluders.kind, occ_hs_start=occluders.hs_start,
        bound_center=f8(bound_center), bound_radius=f8(bound_radius), group_radius=f8(groups.radius),
        centroids=packed.centroids, normals=packed.normals, areas=packed.areas,
        cluster_center=packed.cluster_center, cluster_radius=packed.cluster_radius, tp=f8(tp),
        heights=np.array(heights, dtype=np.float64), coef=np.array(coef, dtype=np.float64),
        tol=np.array(tol, dtype=np.float64), settings=np.array(settings, dtype=np.float64), occ_size=f8(occluders.size),
        occ_rbound=f8(occluders.rbound), occ_hs=f8(occluders.halfspaces), gravity=model.opt.gravity, params=params)
    return tuple(arrays[name] for name, _ in HANDLE_FIELDS)


def friction_arrays(data) -> tuple:
    """The ``fr`` tuple (:data:`FRICTION_FIELDS`) of ``data`` now."""
    return data.efc_type, data.efc_id, data.efc_D, data.efc_aref, data.efc_frictionloss, data.qacc


def mjdata_arrays(data) -> tuple:
    """The ``md`` tuple (:data:`MJDATA_FIELDS`): views of ``data``'s arrays."""
    return tuple(getattr(data, name) for name, _ in MJDATA_FIELDS)
