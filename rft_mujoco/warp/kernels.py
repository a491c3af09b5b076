"""Warp kernels of the batched sand: the CPU coupling's evaluation, per world, inside ``mujoco_warp.step``.

Each kernel ports one part of the CPU path and names it; the numbers agree with it to round-off on the
same state (tests/test_warp.py). Precision: MuJoCo Warp keeps its state in float32; the element pass
(law, depth, sums) runs in float32 like the state it reads, the small dense per-world solves (free
twists, mobility, the rest solve) in float64 -- the rank-revealing Cholesky of
:func:`rft_mujoco.physics.rest.pivoted_solve` squares condition numbers, which float32 cannot hold.

Launch order of one evaluation (:meth:`rft_mujoco.warp.handle.WarpSandHandle._evaluate`)::

    user_part        (nworld, B)   xfrc_applied -> the user's part (the dispatcher's book); broadphase; zeroing
    touch_pass       (nworld, E)   depth of every active element: touch[w, b] = 1 if one is submerged
    [fwd_actuation]                MuJoCo Warp's own, for this step's qfrc_actuator (stabilize only)
    free_twist       (nworld,)     touching groups, free acceleration, Jacobians, mobility, blended twists
      or body_twist  (nworld, B)   stabilize=False: the bodies' own velocities
    force_pass       (nworld, E)   3D-RFT force of every submerged leading element -> per-body wrench sums
    rest_solve       (nworld,)     rest_wrenches + _share + diagnostics (stabilize) or the naive rule
    commit           (nworld, B)   xfrc_applied = user + sand; the book

Work arrays of the one-thread-per-world kernels keep the world index last ((n, w), (n, m, w)): on a GPU the
threads of a warp (consecutive worlds) then read consecutive addresses. Per-body and per-element arrays of
MuJoCo Warp's layout keep it first.

Nothing here allocates or reads back to the host: a whole evaluation can be recorded in a CUDA graph.
Per-element work masks: ``elem_mask`` (1 or nworld, E) int; an element with mask 0 does not exist for
that world (neither touches nor loads), the hook for run-time culling.
"""

from __future__ import annotations

import warp as wp

from rft_mujoco import tol
from rft_mujoco.physics import law, rest

F64 = wp.float64

LEADING_TOL = wp.constant(float(law.LEADING_TOL))
VERTICAL_TOL = wp.constant(float(law.VERTICAL_TOL))
ZERO_SPEED = wp.constant(float(law.ZERO_SPEED))
DEPENDENT_TOL = wp.constant(F64(rest.DEPENDENT_TOL))
WEIGHT_FLOOR = wp.constant(F64(rest.WEIGHT_FLOOR))
CAPACITY_TOL = wp.constant(F64(rest.CAPACITY_TOL))
TINY = wp.constant(F64(tol.TINY))
TIME_RTOL = wp.constant(F64(tol.TIME_RTOL))
TIME_F32_RTOL = wp.constant(F64(4.0e-7))
"""MuJoCo Warp keeps ``time`` in float32: "advanced by at most one step" also allows 4e-7 |t| (about 3 ulp)."""

FLAT = wp.constant(0)
HEIGHTFIELD = wp.constant(1)

NOT_FINITE = wp.constant(1)
"""Bit of ``errors``: a sand wrench came out non-finite; that world got no sand in that evaluation."""
BAD_ACCELERATION = wp.constant(2)
"""Bit of ``errors``: the acceleration without sand was not finite (NaN/inf in ctrl, forces or state)."""


# --- the law (float32; rft_mujoco.physics.law.stress_per_depth) ---------------------------------------
@wp.func
def _cubic(c: wp.array2d(dtype=float), j: int, x1: float, x2: float, x3: float):
    """sum_k c[k, j] t_k(x1, x2, x3), the terms in the order of law.cubic_terms."""
    x11 = x1 * x1
    x22 = x2 * x2
    x33 = x3 * x3
    return (c[0, j] + c[1, j] * x1 + c[2, j] * x2 + c[3, j] * x3 + c[4, j] * x11 + c[5, j] * x22
            + c[6, j] * x33 + c[7, j] * (x1 * x2) + c[8, j] * (x2 * x3) + c[9, j] * (x3 * x1)
            + c[10, j] * (x11 * x1) + c[11, j] * (x22 * x2) + c[12, j] * (x33 * x3) + c[13, j] * (x1 * x22)
            + c[14, j] * (x2 * x11) + c[15, j] * (x2 * x33) + c[16, j] * (x3 * x22) + c[17, j] * (x3 * x11)
            + c[18, j] * (x1 * x33) + c[19, j] * (x1 * x2 * x3))


@wp.func
def stress(n: wp.vec3, v: wp.vec3, g: wp.vec3, c: wp.array2d(dtype=float), mu_surf: float, no_tension: int,
           no_forward: int, no_power: int):
    """law.stress_per_depth / xi_n of one element: unit normal ``n``, unit direction ``v``, unit gravity ``g``."""
    gn = wp.dot(n, g)
    vn = wp.dot(n, v)
    sign = float(1.0)
    if wp.abs(gn) > VERTICAL_TOL:
        if gn <= 0.0:
            sign = -1.0
    elif vn < -LEADING_TOL:
        sign = -1.0
    x1 = wp.dot(v, g)
    x2 = gn * sign
    x3 = vn * sign
    f0 = _cubic(c, 0, x1, x2, x3)
    f1 = _cubic(c, 1, x1, x2, x3)
    f2 = _cubic(c, 2, x1, x2, x3)
    a = f0 * (n * sign) + f1 * v + f2 * g
    an = wp.dot(a, n)
    t = a - an * n
    if no_tension != 0 and an > 0.0:
        an = 0.0
    tmag = wp.length(t)
    cap = float(0.0)
    if tmag > 0.0:
        cap = wp.min(mu_surf * wp.abs(an) / tmag, 1.0)
    t = t * cap
    if no_forward != 0 and wp.dot(t, v) > 0.0:
        t = wp.vec3(0.0, 0.0, 0.0)
    r = an * n + t
    if no_power != 0 and wp.dot(r, v) > 0.0:
        r = wp.vec3(0.0, 0.0, 0.0)
    return r


# --- terrain (float32; rft_mujoco.physics.terrain) ---------------------------------------------------
@wp.func
def depth(p: wp.vec3, g: wp.vec3, w: int, kind: int, flat_height: wp.array(dtype=float),
          tp: wp.array(dtype=float), heights: wp.array2d(dtype=float)):
    """Depth (m) of world point ``p`` below the free surface of world ``w`` (-inf where there is no sand).

    ``tp``: [heightfield max height, x0, x1, y0, y1, outside_none, is_region, rx0, rx1, ry0, ry1] (the
    layout of the compiled CPU kernel's terrain_spec, whose flat height moved to ``flat_height``, (1 or
    nworld,) m).
    """
    if tp[6] != 0.0:
        if not (p[0] >= tp[7] and p[0] <= tp[8] and p[1] >= tp[9] and p[1] <= tp[10]):
            return -wp.inf
    if kind == FLAT:
        return flat_height[w % flat_height.shape[0]] + wp.dot(p, g)
    nrow = heights.shape[0]
    ncol = heights.shape[1]
    u = (p[0] - tp[1]) / (tp[2] - tp[1]) * float(ncol - 1)
    v = (p[1] - tp[3]) / (tp[4] - tp[3]) * float(nrow - 1)
    if not (wp.isfinite(u) and wp.isfinite(v)):
        return -wp.inf
    inside = u >= 0.0 and u <= float(ncol - 1) and v >= 0.0 and v <= float(nrow - 1)
    if tp[5] != 0.0 and not inside:
        return -wp.inf
    u = wp.clamp(u, 0.0, float(ncol - 1))
    v = wp.clamp(v, 0.0, float(nrow - 1))
    i0 = wp.min(int(wp.floor(v)), nrow - 2)
    j0 = wp.min(int(wp.floor(u)), ncol - 2)
    fu = u - float(j0)
    fv = v - float(i0)
    z = ((1.0 - fv) * ((1.0 - fu) * heights[i0, j0] + fu * heights[i0, j0 + 1])
         + fv * ((1.0 - fu) * heights[i0 + 1, j0] + fu * heights[i0 + 1, j0 + 1]))
    return z - p[2]


@wp.func
def gravity_of(gravity: wp.array(dtype=wp.vec3), w: int):
    """Unit gravity direction and magnitude (m/s^2) of world ``w`` (MuJoCo Warp batches opt.gravity)."""
    g = gravity[w % gravity.shape[0]]
    mag = wp.length(g)
    return g / mag, mag


# --- 1. the user's part of xfrc_applied (rft_mujoco.coupling.dispatch) --------------------------------
@wp.kernel
def user_part(body_id: wp.array(dtype=int), xfrc: wp.array2d(dtype=wp.spatial_vector),
              written: wp.array2d(dtype=wp.spatial_vector), added: wp.array2d(dtype=wp.spatial_vector),
              bound_center: wp.array(dtype=wp.vec3), bound_radius: wp.array(dtype=F64),
              xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33), gravity: wp.array(dtype=wp.vec3),
              kind: int, flat_height: wp.array(dtype=float), tp: wp.array(dtype=float),
              user: wp.array2d(dtype=wp.spatial_vector), cand: wp.array2d(dtype=int), touch: wp.array2d(dtype=int),
              wrench: wp.array2d(dtype=wp.spatial_vector), count: wp.array2d(dtype=int),
              max_depth: wp.array2d(dtype=float)):
    """``user = xfrc - added`` on the components the user left as written (dispatch.untouched_components);
    the broadphase (cand[w, b] = 0 when body b's bounding sphere is above the highest point of the sand, as
    SandHandle._touching_numpy: a shortcut, nothing changes); zeroes this evaluation's accumulators."""
    w, b = wp.tid()
    bid = body_id[b]
    center = xpos[w, bid] + xmat[w, bid] * bound_center[b]
    g, _mag = gravity_of(gravity, w)
    top = tp[0]                                   # heightfield: its highest point
    if kind == FLAT:
        top = flat_height[w % flat_height.shape[0]]
    cand[w, b] = 0
    if -wp.dot(center, g) - float(bound_radius[b]) < top:
        cand[w, b] = 1
    x = xfrc[w, body_id[b]]
    wr = written[w, b]
    ad = added[w, b]
    row_same = int(1)
    for c in range(6):
        if x[c] != wr[c]:
            row_same = 0
    out = x
    for c in range(6):
        if x[c] == wr[c] and (row_same == 1 or wr[c] != 0.0):
            out[c] = x[c] - ad[c]
    user[w, b] = out
    touch[w, b] = 0
    wrench[w, b] = wp.spatial_vector()
    count[w, b] = 0
    max_depth[w, b] = 0.0


# --- 2. element passes (float32; rft_mujoco.physics.elements.body_wrenches) ---------------------------
@wp.kernel
def touch_pass(body_id: wp.array(dtype=int), elem_body: wp.array(dtype=int), centroid: wp.array(dtype=wp.vec3),
               elem_mask: wp.array2d(dtype=int), cand: wp.array2d(dtype=int), xpos: wp.array2d(dtype=wp.vec3),
               xmat: wp.array2d(dtype=wp.mat33), gravity: wp.array(dtype=wp.vec3), kind: int,
               flat_height: wp.array(dtype=float), tp: wp.array(dtype=float), heights: wp.array2d(dtype=float),
               touch: wp.array2d(dtype=int)):
    """touch[w, b] = 1 when an active element of attached body b is below the surface (the CPU broadphase and
    depth pre-pass; the broadphase is only a shortcut there and changes nothing)."""
    w, e = wp.tid()
    b = elem_body[e]
    if cand[w, b] == 0 or elem_mask[w % elem_mask.shape[0], e] == 0:
        return
    bid = body_id[b]
    p = xpos[w, bid] + xmat[w, bid] * centroid[e]
    g, _mag = gravity_of(gravity, w)
    if depth(p, g, w, kind, flat_height, tp, heights) > 0.0:
        touch[w, b] = 1


@wp.kernel
def force_pass(body_id: wp.array(dtype=int), elem_body: wp.array(dtype=int), centroid: wp.array(dtype=wp.vec3),
               normal: wp.array(dtype=wp.vec3), area: wp.array(dtype=float), elem_mask: wp.array2d(dtype=int),
               xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33), xipos: wp.array2d(dtype=wp.vec3),
               gravity: wp.array(dtype=wp.vec3), kind: int, flat_height: wp.array(dtype=float),
               tp: wp.array(dtype=float), heights: wp.array2d(dtype=float), coef: wp.array2d(dtype=float),
               xi_per_g: wp.array(dtype=float), mu_surf: wp.array(dtype=float), no_tension: int, no_forward: int,
               no_power: int, touch: wp.array2d(dtype=int), v_lin: wp.array2d(dtype=wp.vec3),
               v_ang: wp.array2d(dtype=wp.vec3), wrench: wp.array2d(dtype=wp.spatial_vector),
               count: wp.array2d(dtype=int), max_depth: wp.array2d(dtype=float)):
    """Each submerged, moving, leading element's force ``alpha |z| dA`` at the motion of its body's COM
    (``v_lin`` m/s, ``v_ang`` rad/s): summed into wrench[w, b] = (force N, torque N m about the body's COM),
    with the count of loaded elements and the deepest loaded depth (m)."""
    w, e = wp.tid()
    if elem_mask[w % elem_mask.shape[0], e] == 0:
        return
    b = elem_body[e]
    if touch[w, b] == 0:
        return
    bid = body_id[b]
    rot = xmat[w, bid]
    p = xpos[w, bid] + rot * centroid[e]
    g, g_mag = gravity_of(gravity, w)
    z = depth(p, g, w, kind, flat_height, tp, heights)
    if not (z > 0.0):
        return
    arm = p - xipos[w, bid]
    vel = v_lin[w, b] + wp.cross(v_ang[w, b], arm)
    speed = wp.length(vel)
    if not (speed > ZERO_SPEED):
        return
    v = vel / speed
    n = rot * normal[e]
    if wp.dot(n, v) < -LEADING_TOL:
        return
    xi_n = xi_per_g[w] * g_mag
    f = stress(n, v, g, coef, mu_surf[w], no_tension, no_forward, no_power) * (xi_n * z * area[e])
    wp.atomic_add(wrench, w, b, wp.spatial_vector(f, wp.cross(arm, f)))
    wp.atomic_add(count, w, b, 1)
    wp.atomic_max(max_depth, w, b, z)


# --- 3. free twists (float64; SandHandle._free_twists and rest.blend) --------------------------------
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
def _cholesky(w: int, mf: wp.array3d(dtype=F64), n: int):
    """mf[:, :, w] := its lower Cholesky factor, in place (lower triangle read and written)."""
    for c in range(n):
        t = mf[c, c, w]
        for k in range(c):
            t -= mf[c, k, w] * mf[c, k, w]
        d = wp.sqrt(t)
        mf[c, c, w] = d
        for r in range(c + 1, n):
            s = mf[r, c, w]
            for k in range(c):
                s -= mf[r, k, w] * mf[c, k, w]
            mf[r, c, w] = s / d


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
def _v3(x: wp.vec3):
    return wp.vec3d(F64(x[0]), F64(x[1]), F64(x[2]))


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
    nb = body_id.shape[0]
    ng_all = group_ref.shape[0]
    dt = F64(timestep[w % timestep.shape[0]])
    # time advanced by at most one step: only then is qfrc_constraint this motion's (_Workspace.follow_time)
    t = F64(time[w])
    step = t - F64(last_time[w])
    lagged = step >= F64(0.0) and step <= dt * (F64(1.0) + TIME_RTOL) + TIME_F32_RTOL * wp.abs(t)
    last_time[w] = time[w]
    # 1. the touching groups, increasing, and each touching body's row among them
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
    ngroups[w] = ng
    if ng == 0:
        return
    # 2. free acceleration: smooth forces (+ the previous solve's constraint forces) + the user's wrenches
    for i in range(nv):
        f = F64(qfrc_passive[w, i]) - F64(qfrc_bias[w, i]) + F64(qfrc_actuator[w, i]) + F64(qfrc_applied[w, i])
        if lagged:
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
            _add_jt_f(w, bb, _v3(xipos[w, bb]), fu, cdof, subtree_com, body_rootid, body_dofnum, body_dofadr,
                      body_parentid, dof_parentid, qacc)
    # the mass matrix (CSR rows, diagonal last) densified and factored
    for i in range(nv):
        for j in range(i + 1):
            mf[i, j, w] = F64(0.0)
        for adr in range(M_rowadr[i], M_rowadr[i] + M_rownnz[i]):
            mf[i, M_colind[adr], w] = F64(M[w, adr])
    _cholesky(w, mf, nv)
    _cholesky_solve(w, mf, nv, qacc, 0)
    finite = int(1)
    for i in range(nv):
        if not wp.isfinite(qacc[0, i, w]):
            finite = 0
    if finite == 0:
        errors[w] = errors[w] | BAD_ACCELERATION
        ngroups[w] = 0
        return
    # 3. Jacobians of the reference points, twists now and free, scaled mobility dt S J M^-1 J^T S
    for r in range(ng):
        bref = body_id[group_ref[active[r, w]]]
        _jacobian(w, bref, _v3(xipos[w, bref]), cdof, subtree_com, body_rootid, body_dofnum, body_dofadr,
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
    # 4. blended twists (rest.blend)
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
    # the blended motion at each touching body's COM
    for b in range(nb):
        r = slot[b, w]
        if r < 0:
            continue
        bref = body_id[group_ref[active[r, w]]]
        ab = _v3(xipos[w, body_id[b]]) - _v3(xipos[w, bref])
        arm[b, w] = ab
        o = 6 * r
        om = wp.vec3d(u[o + 3, w], u[o + 4, w], u[o + 5, w])
        lin = wp.vec3d(u[o, w], u[o + 1, w], u[o + 2, w]) + wp.cross(om, ab)
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


# --- 4. the rest solve (float64; rest.rest_wrenches, rest.pivoted_solve, coupling._share) -------------
@wp.func
def _flow_factor(h: F64, q: F64):
    """rest._flow_factor."""
    if h >= F64(0.0):
        return F64(0.0)
    if q <= F64(0.0):
        return F64(1.0)
    return wp.min(F64(1.0), -h / q)


@wp.func
def _pivoted_solve(w: int, a: wp.array3d(dtype=F64), idx: wp.array2d(dtype=int), m: int,
                   rhs: wp.array2d(dtype=F64), weight: wp.array2d(dtype=F64), x: wp.array2d(dtype=F64),
                   diag0: wp.array2d(dtype=F64), rem: wp.array2d(dtype=F64), order: wp.array2d(dtype=int),
                   kept: wp.array2d(dtype=int), low: wp.array3d(dtype=F64), gram: wp.array3d(dtype=F64),
                   y: wp.array2d(dtype=F64)):
    """rest.pivoted_solve of the matrix a[idx, idx, w] (the first m rows of idx[:, w]); the solution into x[:m, w]."""
    for i in range(m):
        d = a[idx[i, w], idx[i, w], w]
        diag0[i, w] = d
        rem[i, w] = d
        kept[i, w] = 0
        x[i, w] = F64(0.0)
    k = int(0)
    while k < m:
        p = int(-1)
        best = F64(DEPENDENT_TOL)
        for i in range(m):
            if kept[i, w] == 0 and diag0[i, w] > TINY and rem[i, w] > best * diag0[i, w]:
                best = rem[i, w] / diag0[i, w]
                p = i
        if p < 0:
            break
        kept[p, w] = 1
        order[k, w] = p
        piv = wp.sqrt(rem[p, w])
        for i in range(m):
            if kept[i, w] == 1 and i != p:
                continue
            t = a[idx[i, w], idx[p, w], w]
            for j in range(k):
                t -= low[i, j, w] * low[p, j, w]
            low[i, k, w] = t / piv
        for i in range(m):
            if kept[i, w] == 0:
                rem[i, w] = rem[i, w] - low[i, k, w] * low[i, k, w]
        k += 1
    if k == 0:
        return
    for r in range(k):                              # B D B^T, B = a[order[:k], :]
        ir = idx[order[r, w], w]
        for c in range(r + 1):
            ic = idx[order[c, w], w]
            t = F64(0.0)
            for j in range(m):
                ij = idx[j, w]
                t += a[ir, ij, w] * weight[j, w] * a[ic, ij, w]
            gram[r, c, w] = t
    for c in range(k):                              # Cholesky, in place (lower)
        t = gram[c, c, w]
        for j in range(c):
            t -= gram[c, j, w] * gram[c, j, w]
        d = wp.sqrt(TINY)
        if t > TINY:
            d = wp.sqrt(t)
        gram[c, c, w] = d
        for r in range(c + 1, k):
            s = gram[r, c, w]
            for j in range(c):
                s -= gram[r, j, w] * gram[c, j, w]
            gram[r, c, w] = s / d
    for r in range(k):
        t = rhs[order[r, w], w]
        for c in range(r):
            t -= gram[r, c, w] * y[c, w]
        y[r, w] = t / gram[r, r, w]
    for rr in range(k):
        r = k - 1 - rr
        t = y[r, w]
        for c in range(r + 1, k):
            t -= gram[c, r, w] * y[c, w]
        y[r, w] = t / gram[r, r, w]
    for j in range(m):
        ij = idx[j, w]
        t = F64(0.0)
        for r in range(k):
            t += a[idx[order[r, w], w], ij, w] * y[r, w]
        x[j, w] = weight[j, w] * t


@wp.func
def _norm6(x: wp.spatial_vectord, r: F64):
    """|(x[:3], x[3:] / r)|."""
    return wp.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]) / (r * r))


@wp.func
def _sv(x: wp.spatial_vector):
    return wp.spatial_vectord(F64(x[0]), F64(x[1]), F64(x[2]), F64(x[3]), F64(x[4]), F64(x[5]))


@wp.func
def _svf(x: wp.spatial_vectord):
    return wp.spatial_vector(float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4]), float(x[5]))


@wp.kernel
def rest_solve(
        stabilize: int, passive: int, body_group: wp.array(dtype=int), group_radius: wp.array(dtype=F64),
        bound_radius: wp.array(dtype=F64),
        # from the earlier kernels
        ngroups: wp.array(dtype=int), active: wp.array2d(dtype=int), slot: wp.array2d(dtype=int),
        touch: wp.array2d(dtype=int), wrench: wp.array2d(dtype=wp.spatial_vector), count: wp.array2d(dtype=int),
        vs: wp.array2d(dtype=F64), a: wp.array3d(dtype=F64), u: wp.array2d(dtype=F64),
        arm: wp.array2d(dtype=wp.vec3d), v_lin: wp.array2d(dtype=wp.vec3), v_ang: wp.array2d(dtype=wp.vec3),
        # work
        rft_g: wp.array2d(dtype=F64), cap: wp.array2d(dtype=F64), capacity: wp.array2d(dtype=F64),
        rest_flag: wp.array2d(dtype=int), flow: wp.array2d(dtype=int), wv: wp.array2d(dtype=F64),
        idx: wp.array2d(dtype=int), rhs: wp.array2d(dtype=F64), weight: wp.array2d(dtype=F64),
        x: wp.array2d(dtype=F64), diag0: wp.array2d(dtype=F64), rem: wp.array2d(dtype=F64),
        order: wp.array2d(dtype=int), kept: wp.array2d(dtype=int), low: wp.array3d(dtype=F64),
        gram: wp.array3d(dtype=F64), y: wp.array2d(dtype=F64), size: wp.array2d(dtype=F64),
        total: wp.array2d(dtype=F64),
        # outputs
        sand: wp.array2d(dtype=wp.spatial_vector), rft: wp.array2d(dtype=wp.spatial_vector),
        scale: wp.array2d(dtype=float), resting: wp.array2d(dtype=int), status: wp.array(dtype=int),
        errors: wp.array(dtype=int)):
    """One thread per world: the applied wrench of every attached body (``sand``, about its COM) from its
    RFT wrench (``wrench``), and the diagnostics (SandHandle._evaluate_rest / _evaluate_naive, _commit)."""
    w = wp.tid()
    nb = touch.shape[1]
    ng = ngroups[w]
    for b in range(nb):
        sand[w, b] = wp.spatial_vector()
        rft[w, b] = wrench[w, b]
        scale[w, b] = 1.0
        resting[w, b] = 0
    status[w] = 0
    if stabilize != 0 and ng == 0:
        return
    if stabilize == 0:
        for b in range(nb):
            if touch[w, b] == 0:
                continue
            f = _sv(wrench[w, b])
            if passive != 0:
                vl = v_lin[w, b]
                va = v_ang[w, b]
                power = (f[0] * F64(vl[0]) + f[1] * F64(vl[1]) + f[2] * F64(vl[2]) + f[3] * F64(va[0])
                         + f[4] * F64(va[1]) + f[5] * F64(va[2]))
                if power > F64(0.0):
                    f = wp.spatial_vectord()
            sand[w, b] = _svf(f)
    else:
        # the groups' RFT wrenches about their reference points
        n6 = 6 * ng
        for i in range(n6):
            rft_g[i, w] = F64(0.0)
        for b in range(nb):
            r = slot[b, w]
            if r < 0:
                continue
            f = _sv(wrench[w, b])
            fl = wp.vec3d(f[0], f[1], f[2])
            tq = wp.vec3d(f[3], f[4], f[5]) + wp.cross(arm[b, w], fl)
            for c in range(3):
                rft_g[6 * r + c, w] = rft_g[6 * r + c, w] + fl[c]
                rft_g[6 * r + 3 + c, w] = rft_g[6 * r + 3 + c, w] + tq[c]
        # rest.rest_wrenches in scaled coordinates: twists (v, R w), wrenches (f, tau / R)
        for r in range(ng):
            rad = group_radius[active[r, w]]
            nonzero = int(0)
            dsum = F64(0.0)
            for c in range(6):
                xc = rft_g[6 * r + c, w]
                if c >= 3:
                    xc = xc / rad
                cap[6 * r + c, w] = xc
                if xc != F64(0.0):
                    nonzero = 1
                dsum -= rft_g[6 * r + c, w] * u[6 * r + c, w]
            capacity[r, w] = wp.max(dsum, F64(0.0))
            rest_flag[r, w] = nonzero
            flow[r, w] = 0
        again = int(1)
        while again == 1:
            for r in range(ng):
                for c in range(6):
                    wv[6 * r + c, w] = F64(0.0)
                if flow[r, w] != 0:
                    h = F64(0.0)
                    q = F64(0.0)
                    for c in range(6):
                        h += cap[6 * r + c, w] * vs[6 * r + c, w]
                        t = F64(0.0)
                        for e in range(6):
                            t += a[6 * r + c, 6 * r + e, w] * cap[6 * r + e, w]
                        q += cap[6 * r + c, w] * t
                    ff = _flow_factor(h, q)
                    for c in range(6):
                        wv[6 * r + c, w] = ff * cap[6 * r + c, w]
            m = int(0)
            for r in range(ng):
                if rest_flag[r, w] != 0:
                    for c in range(6):
                        idx[m, w] = 6 * r + c
                        m += 1
            over = int(0)
            if m > 0:
                top = F64(0.0)
                for i in range(m):
                    ii = idx[i, w]
                    s = vs[ii, w]
                    for j in range(n6):
                        s += a[ii, j, w] * wv[j, w]
                    rhs[i, w] = s
                    gi = ii // 6
                    t = F64(0.0)
                    for c in range(6):
                        t += cap[6 * gi + c, w] * cap[6 * gi + c, w]
                    weight[i, w] = t
                    top = wp.max(top, t)
                for i in range(m):
                    weight[i, w] = wp.max(weight[i, w], WEIGHT_FLOOR * top)
                _pivoted_solve(w, a, idx, m, rhs, weight, x, diag0, rem, order, kept, low, gram, y)
                for i in range(m):
                    wv[idx[i, w], w] = -x[i, w]
                for r in range(ng):
                    if rest_flag[r, w] != 0:
                        rad = group_radius[active[r, w]]
                        demand = F64(0.0)
                        for c in range(6):
                            sc = F64(1.0)
                            if c >= 3:
                                sc = rad
                            demand -= wv[6 * r + c, w] * u[6 * r + c, w] * sc
                        if demand > capacity[r, w] * (F64(1.0) + CAPACITY_TOL):
                            rest_flag[r, w] = 0
                            flow[r, w] = 1
                            over = 1
            again = over
        # passivity of the whole impulse (rest.passive_scale)
        h = F64(0.0)
        q = F64(0.0)
        for i in range(n6):
            h += wv[i, w] * vs[i, w]
            t = F64(0.0)
            for j in range(n6):
                t += a[i, j, w] * wv[j, w]
            q += wv[i, w] * t
        pscale = F64(1.0)
        if h + F64(0.5) * q > F64(0.0):
            pscale = F64(0.0)
            if h < F64(0.0):
                pscale = _flow_factor(h, q)
        for r in range(ng):
            rad = group_radius[active[r, w]]
            for c in range(6):
                sc = pscale
                if c >= 3:
                    sc = pscale * rad
                wv[6 * r + c, w] = wv[6 * r + c, w] * sc
        # each body's part (coupling._share)
        for r in range(ng):
            total[r, w] = F64(0.0)
        for b in range(nb):
            r = slot[b, w]
            if r < 0:
                continue
            size[b, w] = _norm6(_sv(wrench[w, b]), group_radius[active[r, w]])
            total[r, w] = total[r, w] + size[b, w]
        for b in range(nb):
            r = slot[b, w]
            if r < 0 or total[r, w] <= F64(0.0):
                continue
            o = 6 * r
            rad = group_radius[active[r, w]]
            if rest_flag[r, w] == 0:
                gw = wp.spatial_vectord(rft_g[o, w], rft_g[o + 1, w], rft_g[o + 2, w], rft_g[o + 3, w],
                                        rft_g[o + 4, w], rft_g[o + 5, w])
                aw = wp.spatial_vectord(wv[o, w], wv[o + 1, w], wv[o + 2, w], wv[o + 3, w], wv[o + 4, w],
                                        wv[o + 5, w])
                gn = _norm6(gw, rad)
                ff = F64(0.0)
                if gn > F64(0.0):
                    ff = _norm6(aw, rad) / gn
                sand[w, b] = _svf(_sv(wrench[w, b]) * ff)
            else:
                share = size[b, w] / total[r, w]
                sand[w, b] = _svf(wp.spatial_vectord(share * wv[o, w], share * wv[o + 1, w], share * wv[o + 2, w],
                                                     F64(0.0), F64(0.0), F64(0.0)))
        for r in range(ng):
            if rest_flag[r, w] == 0 or total[r, w] <= F64(0.0):
                continue
            o = 6 * r
            mom = wp.vec3d(wv[o + 3, w], wv[o + 4, w], wv[o + 5, w])
            for b in range(nb):
                if slot[b, w] == r:
                    sb = sand[w, b]
                    mom = mom - wp.cross(arm[b, w], wp.vec3d(F64(sb[0]), F64(sb[1]), F64(sb[2])))
            for b in range(nb):
                if slot[b, w] == r:
                    share = size[b, w] / total[r, w]
                    sb = sand[w, b]
                    sand[w, b] = wp.spatial_vector(sb[0], sb[1], sb[2], float(share * mom[0]),
                                                   float(share * mom[1]), float(share * mom[2]))
    # diagnostics and status (SandHandle._commit)
    st = int(0)
    for b in range(nb):
        if touch[w, b] == 0:
            continue
        rb = bound_radius[b]
        rn = _norm6(_sv(wrench[w, b]), rb)
        sb = sand[w, b]
        if rn > F64(0.0):
            scale[w, b] = float(_norm6(_sv(sb), rb) / rn)
            if stabilize != 0:
                resting[w, b] = rest_flag[slot[b, w], w]
        for c in range(6):
            if not wp.isfinite(sb[c]):
                st = -1
            elif sb[c] != 0.0 and st == 0:
                st = 1
    if st < 0:
        errors[w] = errors[w] | NOT_FINITE
        for b in range(nb):
            sand[w, b] = wp.spatial_vector()
        st = 0
    status[w] = st


# --- 5. xfrc_applied = user + sand (dispatch.Dispatcher.__call__, commit) -----------------------------
@wp.kernel
def commit(body_id: wp.array(dtype=int), user: wp.array2d(dtype=wp.spatial_vector),
           sand: wp.array2d(dtype=wp.spatial_vector), xfrc: wp.array2d(dtype=wp.spatial_vector),
           added: wp.array2d(dtype=wp.spatial_vector), written: wp.array2d(dtype=wp.spatial_vector)):
    w, b = wp.tid()
    s = sand[w, b]
    x = user[w, b] + s
    xfrc[w, body_id[b]] = x
    added[w, b] = s
    written[w, b] = x


@wp.kernel
def remove_sand(body_id: wp.array(dtype=int), xfrc: wp.array2d(dtype=wp.spatial_vector),
                written: wp.array2d(dtype=wp.spatial_vector), added: wp.array2d(dtype=wp.spatial_vector),
                user: wp.array2d(dtype=wp.spatial_vector)):
    """Detach: xfrc_applied rows := the user's part (dispatch.Dispatcher.remove_sand)."""
    w, b = wp.tid()
    x = xfrc[w, body_id[b]]
    wr = written[w, b]
    ad = added[w, b]
    row_same = int(1)
    for c in range(6):
        if x[c] != wr[c]:
            row_same = 0
    out = x
    for c in range(6):
        if x[c] == wr[c] and (row_same == 1 or wr[c] != 0.0):
            out[c] = x[c] - ad[c]
    xfrc[w, body_id[b]] = out
    added[w, b] = wp.spatial_vector()
    written[w, b] = out
