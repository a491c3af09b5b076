"""Free twists of the touching weld groups (float64; ``SandHandle._free_twists`` and :func:`rft_mujoco.physics.rest.blend`):
one thread per world. From MuJoCo Warp's smooth forces (and the previous solve's ``qfrc_constraint``), the
mass matrix and ``cdof``: the acceleration without sand, the Jacobians of the groups' reference points, the
scaled mobility ``dt S J M^-1 J^T S``, the blended twists and the element motions at each body's COM.
``body_twist``: the bodies' own velocities (``stabilize=False``)."""

from __future__ import annotations

import warp as wp

from rft_mujoco.warp.common import BAD_ACCELERATION, F64, TIME_F32_RTOL, TIME_RTOL, cholesky, v3d


@wp.func
def _chain_dof(b: int, body_dofnum: wp.array(dtype=int), body_dofadr: wp.array(dtype=int),
               body_parentid: wp.array(dtype=int)):
    """The last dof of body b's kinematic chain (its own, or its nearest ancestor's), -1 if none."""
    bb = int(b)
    while bb > 0:
        if body_dofnum[bb] > 0:
            return body_dofadr[bb] + body_dofnum[bb] - 1
        bb = body_parentid[bb]
    return -1


@wp.func
def _jacobian(w: int, b: int, p: wp.vec3d, cdof: wp.array2d(dtype=wp.spatial_vector),
              subtree_com: wp.array2d(dtype=wp.vec3), body_rootid: wp.array(dtype=int),
              body_dofnum: wp.array(dtype=int), body_dofadr: wp.array(dtype=int),
              body_parentid: wp.array(dtype=int), dof_parentid: wp.array(dtype=int),
              out: wp.array3d(dtype=F64), row: int):
    """Rows row..row+5 of out[:, :, w] := [linear velocity of world point p (m/s per dof); angular velocity] of
    body b (``mj_jac``), from ``cdof`` (motion axes about subtree_com of the root, rot:lin)."""
    nv = out.shape[1]
    for r in range(6):
        for j in range(nv):
            out[row + r, j, w] = F64(0.0)
    c = subtree_com[w, body_rootid[b]]
    d = p - wp.vec3d(F64(c[0]), F64(c[1]), F64(c[2]))
    j = _chain_dof(b, body_dofnum, body_dofadr, body_parentid)
    while j >= 0:
        cd = cdof[w, j]
        ang = wp.vec3d(F64(cd[0]), F64(cd[1]), F64(cd[2]))
        lin = wp.vec3d(F64(cd[3]), F64(cd[4]), F64(cd[5])) + wp.cross(ang, d)
        for k in range(3):
            out[row + k, j, w] = lin[k]
            out[row + 3 + k, j, w] = ang[k]
        j = dof_parentid[j]


@wp.func
def _add_jt_f(w: int, b: int, p: wp.vec3d, f: wp.spatial_vector, cdof: wp.array2d(dtype=wp.spatial_vector),
              subtree_com: wp.array2d(dtype=wp.vec3), body_rootid: wp.array(dtype=int),
              body_dofnum: wp.array(dtype=int), body_dofadr: wp.array(dtype=int),
              body_parentid: wp.array(dtype=int), dof_parentid: wp.array(dtype=int),
              qfrc: wp.array3d(dtype=F64)):
    """qfrc[0, :, w] += J(b, p)^T (force, torque) (``mj_applyFT``)."""
    c = subtree_com[w, body_rootid[b]]
    d = p - wp.vec3d(F64(c[0]), F64(c[1]), F64(c[2]))
    force = wp.vec3d(F64(f[0]), F64(f[1]), F64(f[2]))
    torque = wp.vec3d(F64(f[3]), F64(f[4]), F64(f[5]))
    j = _chain_dof(b, body_dofnum, body_dofadr, body_parentid)
    while j >= 0:
        cd = cdof[w, j]
        ang = wp.vec3d(F64(cd[0]), F64(cd[1]), F64(cd[2]))
        lin = wp.vec3d(F64(cd[3]), F64(cd[4]), F64(cd[5])) + wp.cross(ang, d)
        qfrc[0, j, w] = qfrc[0, j, w] + wp.dot(lin, force) + wp.dot(ang, torque)
        j = dof_parentid[j]


@wp.func
def _cholesky_solve(w: int, mf: wp.array3d(dtype=F64), n: int, x: wp.array3d(dtype=F64), row: int):
    """x[row, :, w] := M^-1 x[row, :, w] with mf[:, :, w] the lower Cholesky factor of M."""
    for i in range(n):
        s = x[row, i, w]
        for k in range(i):
            s -= mf[i, k, w] * x[row, k, w]
        x[row, i, w] = s / mf[i, i, w]
    for ii in range(n):
        i = n - 1 - ii
        s = x[row, i, w]
        for k in range(i + 1, n):
            s -= mf[k, i, w] * x[row, k, w]
        x[row, i, w] = s / mf[i, i, w]


@wp.func
def follows(w: int, time: wp.array(dtype=float), last_time: wp.array(dtype=float), dt: F64):
    """1 when time advanced by at most one step since the last evaluation (only then are MuJoCo's last
    constraint forces, and the last solve's flags, this motion's: _Workspace.follow_time); records the time."""
    t = F64(time[w])
    step = t - F64(last_time[w])
    lagged = int(0)
    if step >= F64(0.0) and step <= dt * (F64(1.0) + TIME_RTOL) + TIME_F32_RTOL * wp.abs(t):
        lagged = 1
    last_time[w] = time[w]
    return lagged


@wp.func
def touching_groups(w: int, touch: wp.array2d(dtype=int), body_group: wp.array(dtype=int), ng_all: int,
                    active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int)):
    """The touching groups, increasing (``active[:ng, w]``), and each attached body's row among them (``slot``,
    -1 if not touching); returns ng."""
    nb = touch.shape[1]
    ng = int(0)
    for g in range(ng_all):
        hit = int(0)
        for b in range(nb):
            if touch[w, b] != 0 and body_group[b] == g:
                hit = 1
        if hit == 1:
            active[ng, w] = g
            ng += 1
    for b in range(nb):
        slot[b, w] = -1
        if touch[w, b] != 0:
            for r in range(ng):
                if active[r, w] == body_group[b]:
                    slot[b, w] = r
    return ng


@wp.func
def smooth_force(w: int, nbody: int, lagged: int, body_rootid: wp.array(dtype=int),
                 body_dofnum: wp.array(dtype=int), body_dofadr: wp.array(dtype=int),
                 body_parentid: wp.array(dtype=int), dof_parentid: wp.array(dtype=int),
                 attached_index: wp.array(dtype=int), qfrc_passive: wp.array2d(dtype=float),
                 qfrc_bias: wp.array2d(dtype=float), qfrc_actuator: wp.array2d(dtype=float),
                 qfrc_applied: wp.array2d(dtype=float), qfrc_constraint: wp.array2d(dtype=float),
                 cdof: wp.array2d(dtype=wp.spatial_vector), subtree_com: wp.array2d(dtype=wp.vec3),
                 xipos: wp.array2d(dtype=wp.vec3), xfrc: wp.array2d(dtype=wp.spatial_vector),
                 user: wp.array2d(dtype=wp.spatial_vector), qacc: wp.array3d(dtype=F64)):
    """qacc[0, :, w] := the smooth generalized force of this evaluation (passive - bias + actuator + applied,
    + MuJoCo's last constraint force when ``lagged``) + J^T of the user's part of xfrc_applied (N, N m)."""
    nv = qfrc_passive.shape[1]
    for i in range(nv):
        f = F64(qfrc_passive[w, i]) - F64(qfrc_bias[w, i]) + F64(qfrc_actuator[w, i]) + F64(qfrc_applied[w, i])
        if lagged != 0:
            f += F64(qfrc_constraint[w, i])
        qacc[0, i, w] = f
    for bb in range(1, nbody):
        k = attached_index[bb]
        fu = xfrc[w, bb]
        if k >= 0:
            fu = user[w, k]
        nonzero = int(0)
        for c in range(6):
            if fu[c] != 0.0:
                nonzero = 1
        if nonzero == 1:
            _add_jt_f(w, bb, v3d(xipos[w, bb]), fu, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr,
                      body_parentid, dof_parentid, qacc)


@wp.func
def dense_mass(w: int, nv: int, M_rownnz: wp.array(dtype=int), M_rowadr: wp.array(dtype=int),
               M_colind: wp.array(dtype=int), M: wp.array2d(dtype=float), mf: wp.array3d(dtype=F64)):
    """The lower triangle of mf[:, :, w] := MuJoCo Warp's mass matrix (CSR rows, diagonal last), float64."""
    for i in range(nv):
        for j in range(i + 1):
            mf[i, j, w] = F64(0.0)
        for adr in range(M_rowadr[i], M_rowadr[i] + M_rownnz[i]):
            mf[i, M_colind[adr], w] = F64(M[w, adr])


@wp.func
def factor_solve(w: int, nv: int, mf: wp.array3d(dtype=F64), qacc: wp.array3d(dtype=F64)):
    """Factor mf[:, :, w] (Cholesky, in place) and qacc[0, :, w] := its solve; returns 0 if not finite."""
    cholesky(w, mf, nv)
    _cholesky_solve(w, mf, nv, qacc, 0)
    finite = int(1)
    for i in range(nv):
        if not wp.isfinite(qacc[0, i, w]):
            finite = 0
    return finite


@wp.func
def mobility(w: int, ng: int, dt: F64, body_id: wp.array(dtype=int), group_ref: wp.array(dtype=int),
             group_radius: wp.array(dtype=F64), active: wp.array2d(dtype=int), body_rootid: wp.array(dtype=int),
             body_dofnum: wp.array(dtype=int), body_dofadr: wp.array(dtype=int),
             body_parentid: wp.array(dtype=int), dof_parentid: wp.array(dtype=int), qvel: wp.array2d(dtype=float),
             cdof: wp.array2d(dtype=wp.spatial_vector), subtree_com: wp.array2d(dtype=wp.vec3),
             xipos: wp.array2d(dtype=wp.vec3), mf: wp.array3d(dtype=F64), qacc: wp.array3d(dtype=F64),
             jac: wp.array3d(dtype=F64), minv_jt: wp.array3d(dtype=F64), twist: wp.array2d(dtype=F64),
             free: wp.array2d(dtype=F64), vs: wp.array2d(dtype=F64), a: wp.array3d(dtype=F64)):
    """Jacobians of the reference points, twists now and free (m/s, rad/s), H^-1 J^T (``mf``: the factor of
    H), the scaled free twists ``vs`` and the scaled mobility ``a = dt S J H^-1 J^T S``."""
    nv = qvel.shape[1]
    for r in range(ng):
        bref = body_id[group_ref[active[r, w]]]
        _jacobian(w, bref, v3d(xipos[w, bref]), cdof, subtree_com, body_rootid, body_dofnum, body_dofadr,
                  body_parentid, dof_parentid, jac, 6 * r)
    n6 = 6 * ng
    for i in range(n6):
        tw = F64(0.0)
        s = F64(0.0)
        for j in range(nv):
            tw += jac[i, j, w] * F64(qvel[w, j])
            s += jac[i, j, w] * qacc[0, j, w]
            minv_jt[i, j, w] = jac[i, j, w]
        twist[i, w] = tw
        free[i, w] = tw + dt * s
        _cholesky_solve(w, mf, nv, minv_jt, i)
    for i in range(n6):
        si = F64(1.0)
        if i % 6 >= 3:
            si = group_radius[active[i // 6, w]]
        vs[i, w] = free[i, w] * si
        for j in range(i + 1):
            sj = F64(1.0)
            if j % 6 >= 3:
                sj = group_radius[active[j // 6, w]]
            s = F64(0.0)
            for c in range(nv):
                s += jac[i, c, w] * minv_jt[j, c, w]
            x = dt * (si * s * sj)
            a[i, j, w] = x
            a[j, i, w] = x


@wp.func
def blend(w: int, ng: int, active: wp.array2d(dtype=int), group_radius: wp.array(dtype=F64),
          twist: wp.array2d(dtype=F64), free: wp.array2d(dtype=F64), u: wp.array2d(dtype=F64)):
    """u := the blended twists of the touching groups (rest.blend), m/s and rad/s."""
    for r in range(ng):
        rad = group_radius[active[r, w]]
        o = 6 * r
        sl = wp.vec3d(free[o, w] - twist[o, w], free[o + 1, w] - twist[o + 1, w], free[o + 2, w] - twist[o + 2, w])
        sa = wp.vec3d(free[o + 3, w] - twist[o + 3, w], free[o + 4, w] - twist[o + 4, w],
                      free[o + 5, w] - twist[o + 5, w])
        vl = wp.vec3d(twist[o, w], twist[o + 1, w], twist[o + 2, w])
        va = wp.vec3d(twist[o + 3, w], twist[o + 4, w], twist[o + 5, w])
        s = wp.length(sl) + rad * wp.length(sa)
        vv = wp.length(vl) + rad * wp.length(va)
        wgt = F64(0.0)
        if s > F64(0.0):
            wgt = s * s / (vv * vv + s * s)
        for c in range(6):
            u[o + c, w] = twist[o + c, w] + wgt * (free[o + c, w] - twist[o + c, w])


@wp.func
def com_motion(w: int, b: int, r: int, body_id: wp.array(dtype=int), group_ref: wp.array(dtype=int),
               active: wp.array2d(dtype=int), xipos: wp.array2d(dtype=wp.vec3), u: wp.array2d(dtype=F64),
               arm: wp.array2d(dtype=wp.vec3d)):
    """arm[b, w] := body b's COM from its group's reference point (m); returns the motion of group row r's
    twist ``u`` at that COM (m/s, rad/s)."""
    bref = body_id[group_ref[active[r, w]]]
    ab = v3d(xipos[w, body_id[b]]) - v3d(xipos[w, bref])
    arm[b, w] = ab
    o = 6 * r
    om = wp.vec3d(u[o + 3, w], u[o + 4, w], u[o + 5, w])
    return wp.vec3d(u[o, w], u[o + 1, w], u[o + 2, w]) + wp.cross(om, ab), om


@wp.kernel
def free_twist(
        # model
        nbody: int, body_rootid: wp.array(dtype=int), body_dofnum: wp.array(dtype=int),
        body_dofadr: wp.array(dtype=int), body_parentid: wp.array(dtype=int), dof_parentid: wp.array(dtype=int),
        M_rownnz: wp.array(dtype=int), M_rowadr: wp.array(dtype=int), M_colind: wp.array(dtype=int),
        timestep: wp.array(dtype=float),
        # the handle
        body_id: wp.array(dtype=int), attached_index: wp.array(dtype=int), body_group: wp.array(dtype=int),
        group_ref: wp.array(dtype=int), group_radius: wp.array(dtype=F64),
        # MuJoCo Warp data
        time: wp.array(dtype=float), qvel: wp.array2d(dtype=float), qfrc_passive: wp.array2d(dtype=float),
        qfrc_bias: wp.array2d(dtype=float), qfrc_actuator: wp.array2d(dtype=float),
        qfrc_applied: wp.array2d(dtype=float), qfrc_constraint: wp.array2d(dtype=float),
        M: wp.array2d(dtype=float), cdof: wp.array2d(dtype=wp.spatial_vector),
        subtree_com: wp.array2d(dtype=wp.vec3), xipos: wp.array2d(dtype=wp.vec3),
        xfrc: wp.array2d(dtype=wp.spatial_vector), user: wp.array2d(dtype=wp.spatial_vector),
        touch: wp.array2d(dtype=int),
        # state and outputs
        last_time: wp.array(dtype=float), errors: wp.array(dtype=int), ngroups: wp.array(dtype=int),
        active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int), mf: wp.array3d(dtype=F64),
        qacc: wp.array3d(dtype=F64), jac: wp.array3d(dtype=F64), minv_jt: wp.array3d(dtype=F64),
        twist: wp.array2d(dtype=F64), free: wp.array2d(dtype=F64), u: wp.array2d(dtype=F64),
        vs: wp.array2d(dtype=F64), a: wp.array3d(dtype=F64), arm: wp.array2d(dtype=wp.vec3d),
        v_lin: wp.array2d(dtype=wp.vec3), v_ang: wp.array2d(dtype=wp.vec3)):
    """One thread per world: SandHandle._free_twists + the blend of _evaluate_rest (compiled rest.evaluate
    steps 1-4). Outputs the touching groups (``active[:ngroups[w], w]``, increasing), each attached body's
    row among them (``slot``, -1 if not touching), the scaled free twists ``vs`` and scaled mobility
    ``a = dt S J M^-1 J^T S`` of rest.rest_wrenches, the blended twists ``u`` (unscaled), and the element
    motions (``v_lin``, ``v_ang``) at each touching body's COM."""
    w = wp.tid()
    nv = qvel.shape[1]
    dt = F64(timestep[w % timestep.shape[0]])
    lagged = follows(w, time, last_time, dt)
    ng = touching_groups(w, touch, body_group, group_ref.shape[0], active, slot)
    ngroups[w] = ng
    if ng == 0:
        return
    smooth_force(w, nbody, lagged, body_rootid, body_dofnum, body_dofadr, body_parentid, dof_parentid,
                 attached_index, qfrc_passive, qfrc_bias, qfrc_actuator, qfrc_applied, qfrc_constraint, cdof,
                 subtree_com, xipos, xfrc, user, qacc)
    dense_mass(w, nv, M_rownnz, M_rowadr, M_colind, M, mf)
    if factor_solve(w, nv, mf, qacc) == 0:
        errors[w] = errors[w] | BAD_ACCELERATION
        ngroups[w] = 0
        return
    mobility(w, ng, dt, body_id, group_ref, group_radius, active, body_rootid, body_dofnum, body_dofadr,
             body_parentid, dof_parentid, qvel, cdof, subtree_com, xipos, mf, qacc, jac, minv_jt, twist, free, vs, a)
    blend(w, ng, active, group_radius, twist, free, u)
    for b in range(body_id.shape[0]):
        r = slot[b, w]
        if r < 0:
            continue
        lin, om = com_motion(w, b, r, body_id, group_ref, active, xipos, u, arm)
        v_lin[w, b] = wp.vec3(float(lin[0]), float(lin[1]), float(lin[2]))
        v_ang[w, b] = wp.vec3(float(om[0]), float(om[1]), float(om[2]))


@wp.kernel
def body_twist(body_id: wp.array(dtype=int), body_rootid: wp.array(dtype=int),
               cvel: wp.array2d(dtype=wp.spatial_vector), xipos: wp.array2d(dtype=wp.vec3),
               subtree_com: wp.array2d(dtype=wp.vec3), v_lin: wp.array2d(dtype=wp.vec3),
               v_ang: wp.array2d(dtype=wp.vec3)):
    """stabilize=False: each body's own COM velocity from ``cvel`` (linear part at subtree_com of the root)."""
    w, b = wp.tid()
    bid = body_id[b]
    cv = cvel[w, bid]
    om = wp.vec3(cv[0], cv[1], cv[2])
    v_ang[w, b] = om
    v_lin[w, b] = wp.vec3(cv[3], cv[4], cv[5]) + wp.cross(om, xipos[w, bid] - subtree_com[w, body_rootid[bid]])
